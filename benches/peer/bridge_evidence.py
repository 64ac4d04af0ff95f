"""The log evidence of `mrbp sample --sampler smc` against bridge sampling
done outside mrbp, on the same posterior.

    python benches/peer/bridge_evidence.py [MANIFEST] [--current 1.0]
        [--out DIR] [--substeps 8] [--draws 2000] [--repeats 8]

MANIFEST defaults to the bundled virtual campaign (data/campaign.toml).
The script calibrates its runs at one current with mrbp twice (release
binary in target/release; `--exact-input`, Gaussian noise, no model terms,
a fixed `--substeps` so that both integrations are close to the exact
solution): once by sequential Monte Carlo (`--sampler smc`: its log
evidence and standard error in calibration.toml's [smc]) and once by the
ensemble sampler alone (its draws). Then, written here and independent of
mrbp:

* the posterior in (ln θ, ln σ_run): the priors read from mrbp's
  config.toml and normalised here (log-normal in θ truncated to its
  physical range: a truncated normal in ln θ; log-uniform σ: uniform in
  ln σ), Gaussian residuals with their 2π, the B-P law for shear integrated
  by explicit Euler with Richardson extrapolation (numba) at mrbp's
  sub-steps — the same discretised posterior; at twice as many the shift
  of ln p is printed, the discretisation's share of the evidence — driven
  by the strain mrbp's bands.parquet says drives the model (`gamma_model`:
  the measured strain smoothed), against `tau_obs`;
* the log evidence by bridge sampling (Meng & Wong's iterative optimal
  bridge) between the posterior and a Gaussian fitted to one half of the
  ensemble sampler's draws, the other half (thinned to near independence)
  and as many Gaussian draws the two sides; its standard error the larger
  of the spread over `--repeats` splits and proposal draws (over √R) and
  one repeat's relative mean-square error (Frühwirth-Schnatter, 2004);
* the posterior means by importance sampling from the same Gaussian
  (self-normalised), against the ensemble sampler's.

Before the evidence, the script's log-density is compared with mrbp's at
the posterior draws (chains.parquet's `log_prob`): their difference must be
one constant (mrbp leaves the normalising constants out while sampling),
equal to mrbp's `log_evidence − log_integral`; its spread over the draws is
the two integrations' disagreement.

Needs numpy, scipy, numba, pandas, pyarrow (pip).
"""
import argparse, math, multiprocessing, os, pathlib, subprocess, sys, tomllib

import numba
import numpy as np
import pandas as pd
from scipy.special import logsumexp, ndtr

from bp_numba import bp_path

NAMES = ["G", "R0", "R1", "D1", "m1", "m2", "n"]


@numba.njit(cache=False)
def residual_ss(theta, t, gamma, tau_obs, substeps):
    """Σ over samples 1.. of (τ_obs − τ)², τ Richardson-extrapolated from
    `substeps` and twice as many; inf where the path is not finite."""
    coarse = bp_path(theta, t, gamma, substeps)
    fine = bp_path(theta, t, gamma, 2 * substeps)
    ss = 0.0
    for k in range(1, len(t)):
        r = tau_obs[k] - (2.0 * fine[k] - coarse[k])
        ss += r * r
    if not math.isfinite(ss):
        return math.inf
    return ss


class Posterior:
    """The posterior density in (ln θ, ln σ_run), normalised priors and
    likelihood, as written in the module's docstring."""

    def __init__(self, config, runs, substeps):
        self.runs, self.substeps = runs, substeps
        priors = config["prior"]
        self.mu = np.array([math.log(priors[p]["median"]) for p in NAMES])
        self.sd = np.array([priors[p]["sd_log"] for p in NAMES])
        self.lo = np.log([priors[p]["lower"] for p in NAMES])
        self.hi = np.log([priors[p]["upper"] for p in NAMES])
        for p in NAMES:
            assert priors[p]["kind"] == "log-normal", p
        mass = ndtr((self.hi - self.mu) / self.sd) - ndtr((self.lo - self.mu) / self.sd)
        self.theta_norm = float(np.sum(-np.log(self.sd) - 0.5 * math.log(2 * math.pi) - np.log(mass)))
        s_lo, s_hi = config["sigma_bounds_pa"]
        self.ls_lo, self.ls_hi = math.log(s_lo), math.log(s_hi)
        self.sigma_norm = -len(runs) * math.log(self.ls_hi - self.ls_lo)

    def __call__(self, x):
        lt = x[:7]
        if np.any(lt < self.lo) or np.any(lt > self.hi):
            return -np.inf
        lp = self.theta_norm - 0.5 * np.sum(((lt - self.mu) / self.sd) ** 2) + self.sigma_norm
        theta = np.exp(lt)
        for (t, gamma, tau), ls in zip(self.runs, x[7:]):
            if not (self.ls_lo <= ls <= self.ls_hi):
                return -np.inf
            ss = residual_ss(theta, t, gamma, tau, self.substeps)
            if not math.isfinite(ss):
                return -np.inf
            m = len(t) - 1
            lp += -m * ls - 0.5 * ss * math.exp(-2.0 * ls) - 0.5 * m * math.log(2 * math.pi)
        return lp


POSTERIOR = None


def setup(posterior):
    global POSTERIOR
    POSTERIOR = posterior


def evaluate(x):
    return POSTERIOR(x)


def gaussian_logpdf(xs, mean, chol):
    z = np.linalg.solve(chol, (xs - mean).T).T
    d = xs.shape[1]
    return -0.5 * np.sum(z * z, axis=1) - np.sum(np.log(np.diag(chol))) - 0.5 * d * math.log(2 * math.pi)


def bridge(l1, l2, iterations=1000):
    """ln Z by Meng & Wong's iterative optimal bridge: l1 = ln p − ln q at
    posterior draws, l2 = ln p − ln q at proposal draws (p unnormalised)."""
    n1, n2 = len(l1), len(l2)
    s1, s2 = n1 / (n1 + n2), n2 / (n1 + n2)
    shift = np.median(l1)
    a, b = l1 - shift, l2 - shift
    log_r = 0.0
    for _ in range(iterations):
        num = logsumexp(b - np.logaddexp(math.log(s1) + b, math.log(s2) + log_r)) - math.log(n2)
        den = logsumexp(-np.logaddexp(math.log(s1) + a, math.log(s2) + log_r)) - math.log(n1)
        new = num - den
        if abs(new - log_r) < 1e-12:
            log_r = new
            break
        log_r = new
    # Frühwirth-Schnatter's relative mean-square error (independent draws)
    f1 = np.exp(b - np.logaddexp(math.log(s1) + b, math.log(s2) + log_r))
    f2 = np.exp(-np.logaddexp(math.log(s1) + a, math.log(s2) + log_r))
    re2 = np.var(f1) / np.mean(f1) ** 2 / n2 + np.var(f2) / np.mean(f2) ** 2 / n1
    return log_r + shift, math.sqrt(re2)


def mrbp(binary, *args):
    subprocess.run([str(binary), *map(str, args)], check=True, stdout=subprocess.DEVNULL)


def main():
    repo = pathlib.Path(__file__).resolve().parents[2]
    ap = argparse.ArgumentParser()
    ap.add_argument("manifest", type=pathlib.Path, nargs="?", default=repo / "data" / "campaign.toml")
    ap.add_argument("--current", type=float, default=1.0)
    ap.add_argument("--out", type=pathlib.Path, default=repo / "target" / "peer-bridge")
    ap.add_argument("--substeps", type=int, default=8)
    ap.add_argument("--draws", type=int, default=2000, help="posterior draws (and as many proposal draws) per repeat")
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    binary = repo / "target" / "release" / "mrbp"
    common = ["--current", args.current, "--exact-input", "--substeps", args.substeps, "--seed", args.seed, "--force"]
    smc_dir, ens_dir = args.out / "smc", args.out / "ensemble"
    mrbp(binary, "sample", args.manifest, "--sampler", "smc", "--out", smc_dir, *common)
    mrbp(binary, "sample", args.manifest, "--out", ens_dir, *common)
    mrbp(binary, "predict", ens_dir, "--draws", 20, "--replicates", 2)
    # mrbp samples the B-P law in its hardening coordinates, whose Jacobian
    # its log-densities carry; sampled in ln θ its log-density differs from
    # the one written here by the normalising constants alone
    log_dir = args.out / "log-coordinates"
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "settings.toml").write_text('[sampler]\ncoordinates = "log"\n')
    mrbp(binary, "sample", args.manifest, "--out", log_dir / "calibration", "--config", log_dir / "settings.toml", "--steps", 20, *common)
    smc = tomllib.loads((smc_dir / "calibration.toml").read_text())["smc"]
    config = tomllib.loads((ens_dir / "config.toml").read_text())
    assert config["likelihood"]["noise"] == "gaussian" and config["likelihood"]["memory"] == "independent"
    assert not config["terms"]["force_offset"] and not config["terms"]["gas_spring"]
    record = tomllib.loads((ens_dir / "calibration.toml").read_text())

    bands = pd.read_parquet(ens_dir / "bands.parquet")
    ids = list(dict.fromkeys(bands["run"]))
    runs = []
    for run in ids:
        b = bands[bands["run"] == run]
        runs.append((b["time_s"].to_numpy(), b["gamma_model"].to_numpy(), b["tau_obs"].to_numpy()))
    posterior = Posterior(config, runs, args.substeps)
    finer = Posterior(config, runs, 2 * args.substeps)

    chains = pd.read_parquet(ens_dir / "chains.parquet")
    chains = chains[chains["draw"] >= record["burn_in"]]
    sigma = [f"sigma_{r}" for r in ids]
    x_all = np.column_stack([np.log(chains[c].to_numpy()) for c in NAMES + sigma])
    lp_mrbp_all = chains["log_prob"].to_numpy()

    rng = np.random.default_rng(args.seed)
    with multiprocessing.Pool(os.cpu_count(), initializer=setup, initargs=(posterior,)) as pool:
        # the two log-densities at the same draws: one constant apart
        offset = smc["log_evidence"] - smc["log_integral"]
        print(f"{len(ids)} runs at {args.current} A, {sum(len(r[0]) for r in runs)} samples; explicit Euler at {args.substeps} and {2 * args.substeps} sub-steps, Richardson-extrapolated, in mrbp and here")
        print(f"mrbp's normalising constants (log_evidence − log_integral): {offset:.4f}")
        in_log = pd.read_parquet(log_dir / "calibration" / "chains.parquet")
        for what, frame in [("ln θ", in_log), ("hardening coordinates (their Jacobian in it)", chains)]:
            rows = rng.choice(len(frame), size=200, replace=False)
            x = np.column_stack([np.log(frame[c].to_numpy()[rows]) for c in NAMES + sigma])
            diff = np.array(pool.map(evaluate, list(x))) - frame["log_prob"].to_numpy()[rows]
            print(f"ln p here − ln p of mrbp sampled in {what}, 200 draws: mean {diff.mean():.4f}, sd {diff.std():.2e}, range {np.ptp(diff):.2e}")
        rows = rng.choice(len(in_log), size=50, replace=False)
        x = np.column_stack([np.log(in_log[c].to_numpy()[rows]) for c in NAMES + sigma])
        shift = np.array([finer(v) for v in x]) - np.array(pool.map(evaluate, list(x)))
        print(f"ln p at twice the sub-steps − ln p, 50 draws: mean {shift.mean():+.4f}, sd {shift.std():.4f} (the discretisation's share of ln Z, not in the comparison below)")

        estimates, errors, means = [], [], []
        for r in range(args.repeats):
            order = rng.permutation(len(x_all))
            half = len(order) // 2
            fit, rest = x_all[order[:half]], order[half:]
            mean = fit.mean(axis=0)
            chol = np.linalg.cholesky(np.cov(fit.T))
            # the posterior side: draws spread over the whole chains (the
            # ensemble sampler's τ is 1–2 steps: every walker's every 4th)
            picked = rest[:: max(1, len(rest) // args.draws)][: args.draws]
            post_x = x_all[picked]
            prop_x = mean + rng.standard_normal((args.draws, len(mean))) @ chol.T
            lp_post = np.array(pool.map(evaluate, list(post_x)))
            lp_prop = np.array(pool.map(evaluate, list(prop_x)))
            l1 = lp_post - gaussian_logpdf(post_x, mean, chol)
            l2 = lp_prop - gaussian_logpdf(prop_x, mean, chol)
            log_z, re = bridge(l1, l2)
            estimates.append(log_z)
            errors.append(re)
            w = np.exp(l2 - logsumexp(l2))
            means.append(w @ np.exp(prop_x[:, :7]))
            print(f"  repeat {r + 1}: ln Z {log_z:.3f} (relative error {re:.4f}); proposal ESS {1 / np.sum(w * w):.0f} of {args.draws}")

    estimates = np.array(estimates)
    # the repeats share the ensemble sampler's draws: their spread / √R
    # can be below one repeat's own error, the larger is quoted
    log_z = estimates.mean()
    se = max(estimates.std(ddof=1) / math.sqrt(len(estimates)), float(np.mean(errors)))
    smc_se = max(smc["se_weights"], smc["se_spread"])
    combined = math.hypot(se, smc_se)
    print(f"bridge sampling (here): ln Z = {log_z:.3f} ± {se:.3f} (the larger of the spread of {len(estimates)} repeats / √{len(estimates)}, {estimates.std(ddof=1) / math.sqrt(len(estimates)):.3f}, and one repeat's relative error, {np.mean(errors):.3f})")
    print(f"mrbp --sampler smc:      ln Z = {smc['log_evidence']:.3f} ± {smc_se:.3f} ({smc['evidence_of']})")
    print(f"difference {smc['log_evidence'] - log_z:+.3f} nat = {(smc['log_evidence'] - log_z) / combined:+.2f} combined standard errors")

    summary = pd.read_parquet(ens_dir / "summary.parquet").set_index("parameter")
    here = np.mean(means, axis=0)
    print("posterior means, mrbp's ensemble sampler against importance sampling here (in mrbp's sd):")
    for i, name in enumerate(NAMES):
        m, s = summary.loc[name, "mean"], summary.loc[name, "sd"]
        print(f"  {name:3} {m:.5e} {here[i]:.5e} ({(here[i] - m) / s:+.3f} sd)")
    smc_summary = pd.read_parquet(smc_dir / "summary.parquet").set_index("parameter")
    print("posterior means, mrbp --sampler smc against the ensemble sampler (in its sd):")
    for name in NAMES:
        m, s = summary.loc[name, "mean"], summary.loc[name, "sd"]
        print(f"  {name:3} {(smc_summary.loc[name, 'mean'] - m) / s:+.3f} sd")


if __name__ == "__main__":
    sys.exit(main())
