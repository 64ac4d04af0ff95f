"""An independent reference for a calibration's posterior: self-normalised
importance sampling, no Markov chain involved.

    python benches/reference/importance_sampling.py DIR [OTHER_DIR ...]
        [--draws 150000] [--components 24] [--seed 3]

DIR is a calibration folder; its chains (and those of OTHER_DIRs, other
calibrations of the same runs, e.g. long runs of other moves) only shape the
proposal: a Gaussian mixture fitted to their draws in the sampler's
coordinates (standardised), each covariance widened by 1.3², with 15 % of
a broad Student-t (ν = 3, 4× the draws' covariance) so that the proposal
covers what the chains missed. Draws from it are weighed by p/q, p being
the posterior's log-density at each (`examples/log_density_at.rs`), so the
estimates do not inherit the chains' errors. Prints the effective sample
size, the Pareto k̂ of the largest weights (< 0.7: trustworthy), and for
every coordinate the mean, sd and 1/5/50/95/99 % quantiles with the chains'
own beside them.

Needs numpy, pyarrow, scipy and scikit-learn, and the example built:
cargo build --release --example log_density_at
"""
import argparse
import pathlib
import subprocess
import tomllib

import numpy as np
import pyarrow.parquet as pq
from scipy.special import logsumexp
from scipy.stats import genpareto, multivariate_normal, multivariate_t
from sklearn.mixture import GaussianMixture

ROOT = pathlib.Path(__file__).resolve().parents[2]
HARNESS = ROOT / "target" / "release" / "examples" / "log_density_at"
QUANTILES = [0.01, 0.05, 0.5, 0.95, 0.99]
WIDEN, DEFENSIVE = 1.3**2, 0.15


def harness(cal, mode, points=None):
    text = None if points is None else "\n".join(",".join(repr(float(v)) for v in p) for p in points)
    out = subprocess.run([str(HARNESS), cal, mode], input=text, capture_output=True, text=True, check=True).stdout
    return out.strip().split("\n")


def chain_draws(folder, names, most=60000):
    t = pq.read_table(f"{folder}/chains.parquet")
    burn = tomllib.load(open(f"{folder}/calibration.toml", "rb")).get("burn_in", 0)
    keep = np.asarray(t.column("draw")) >= burn
    si = np.column_stack([np.asarray(t.column(n))[keep] for n in names])
    return si[:: max(1, len(si) // most)]


def weighted_quantile(v, w, q):
    order = np.argsort(v)
    return v[order][np.searchsorted(np.cumsum(w[order]), q)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("others", nargs="*")
    ap.add_argument("--draws", type=int, default=150000)
    ap.add_argument("--components", type=int, default=24)
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
    names = harness(a.dir, "names")[0].split(",")
    d = len(names)
    own = chain_draws(a.dir, names)
    si = np.vstack([own] + [chain_draws(o, names) for o in a.others])
    x = np.array([[float(v) for v in line.split(",")[:d]] for line in harness(a.dir, "si", si)])
    centre, scale = x.mean(0), x.std(0)
    y = (x - centre) / scale
    gm = GaussianMixture(a.components, covariance_type="full", random_state=0, reg_covar=1e-8).fit(y)
    parts = [(np.log(w * (1 - DEFENSIVE)), m, c * WIDEN) for w, m, c in zip(gm.weights_, gm.means_, gm.covariances_)]
    broad = multivariate_t(np.zeros(d), np.cov(y.T) * 4, df=3)

    rng = np.random.default_rng(a.seed)
    n_broad = rng.binomial(a.draws, DEFENSIVE)
    counts = rng.multinomial(a.draws - n_broad, gm.weights_)
    z = np.vstack([rng.multivariate_normal(m, c, size=k) for (_, m, c), k in zip(parts, counts)] + [broad.rvs(size=n_broad, random_state=rng)])
    log_q = logsumexp(np.array([lw + multivariate_normal(m, c).logpdf(z) for lw, m, c in parts] + [np.log(DEFENSIVE) + broad.logpdf(z)]), axis=0)
    points = z * scale + centre
    log_p = np.array([float(line.split(",")[-1]) for line in harness(a.dir, "x", points)])
    log_w = np.where(np.isfinite(log_p), log_p - log_q, -np.inf)
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    finite = np.sort(log_w[np.isfinite(log_w)])
    m = int(min(0.2 * len(finite), 3 * np.sqrt(len(finite))))
    k_hat = genpareto.fit(np.exp(finite[-m:] - finite[-m - 1]) - 1, floc=0)[0]
    print(f"{a.draws} draws, {np.isfinite(log_p).mean():.3f} inside the support, effective sample size {1 / np.sum(w**2):.0f}, Pareto k̂ {k_hat:.2f}")

    values = np.array([[float(v) for v in line.split(",")] for line in harness(a.dir, "to-si", points)])
    print(f"{'coordinate':34s} {'':8s} {'mean':>11s} {'sd':>10s} " + " ".join(f"{'q%02d' % (q * 100):>11s}" for q in QUANTILES))
    for j, name in enumerate(names):
        v = values[:, j]
        mean = np.sum(w * v)
        sd = np.sqrt(np.sum(w * (v - mean) ** 2))
        qs = [weighted_quantile(v, w, q) for q in QUANTILES]
        print(f"{name:34s} {'IS':8s} {mean:11.5g} {sd:10.4g} " + " ".join(f"{q:11.5g}" for q in qs))
        c = own[:, j]
        print(f"{'':34s} {'chains':8s} {c.mean():11.5g} {c.std():10.4g} " + " ".join(f"{q:11.5g}" for q in np.quantile(c, QUANTILES)))


if __name__ == "__main__":
    main()
