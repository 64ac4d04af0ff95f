"""The peer of `mrbp sample`: emcee with a numba-compiled B-P likelihood, on
the same posterior, run side by side with mrbp on the same machine.

    python benches/peer/emcee_numba.py CAMPAIGN_DIR [--current 1.0]

CAMPAIGN_DIR holds a campaign made by `mrbp synth` or measured records in
the campaign format (see docs/performance.md for both). The script
calibrates it with mrbp (release binary in target/release; `--exact-input`,
Gaussian noise, no model terms), then samples the same posterior with
emcee: ln θ of the
seven B-P parameters and ln σ of each run, the same priors, Gaussian noise,
the measured strain smoothed by the same local cubic (±2 ms), explicit Euler
with 4 fixed sub-steps per sample (the paper's integrator, as a Python user
would write it), 32 walkers × 1500 steps started around mrbp's MAP, its
log-densities spread over as many processes as mrbp has threads (emcee's
`pool`). Both are scored as ArviZ scores them: the smallest bulk ESS over
the seven B-P parameters per second of wall time (numba's compilation not
counted).

Needs numpy, scipy, numba, emcee, arviz, pandas, pyarrow (pip).
"""
import argparse, math, multiprocessing, os, pathlib, subprocess, sys, time, tomllib

import arviz as az
import emcee
import numba
import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from bp_numba import bp_path

NAMES = ["G", "R0", "R1", "D1", "m1", "m2", "n"]
# the default priors of mrbp: log-normal on ln θ whose ±1 sd spans the
# plausible range, truncated to the physical range (docs/calibration.md)
PLAUSIBLE = [(1e4, 1e6), (5e4, 3e5), (5e4, 5e5), (1e4, 1e5), (1e-6, 1e-4), (1e-4, 1e-2), (0.5, 3.0)]
PHYSICAL = [(1e3, 1e8), (1e3, 1e7), (1e3, 1e7), (1e1, 1e7), (1e-9, 1e-2), (1e-7, 1.0), (0.1, 10.0)]
PRIOR_MU = np.array([0.5 * (math.log(a) + math.log(b)) for a, b in PLAUSIBLE])
PRIOR_SD = np.array([0.5 * (math.log(b) - math.log(a)) for a, b in PLAUSIBLE])
LO = np.log([a for a, _ in PHYSICAL])
HI = np.log([b for _, b in PHYSICAL])


@numba.njit(cache=False, fastmath=False)
def residual_ss(theta, t, gamma, tau_obs, substeps):
    path = bp_path(theta, t, gamma, substeps)
    ss = 0.0
    for k in range(1, len(t)):
        r = tau_obs[k] - path[k]
        ss += r * r
    if not math.isfinite(ss):
        return math.inf
    return ss


def load(campaign, current):
    manifest = tomllib.loads((campaign / "campaign.toml").read_text())
    area, gap = manifest["geometry"]["area_m2"], manifest["geometry"]["gap_m"]
    runs = []
    for run in manifest["run"]:
        if abs(run["current_a"] - current) > 1e-3:
            continue
        d = pd.read_csv(campaign / run["file"])
        t = d.time_s.to_numpy()
        gamma = (d.displacement_m.to_numpy() - d.displacement_m.iloc[0]) / gap
        half = round(2e-3 / (t[1] - t[0]))
        smooth = savgol_filter(gamma, 2 * half + 1, 3) if half >= 2 else gamma
        smooth[0] = gamma[0]
        runs.append((run["id"], t, smooth, d.force_n.to_numpy() / area))
    return runs


RUNS, SUBSTEPS = None, None


def setup(runs, substeps):
    """A pool worker's data, sent once instead of with every call."""
    global RUNS, SUBSTEPS
    RUNS, SUBSTEPS = runs, substeps
    log_prob(np.concatenate([PRIOR_MU, np.full(len(runs), 5.0)]))  # compile


def log_prob(x):
    runs, substeps = RUNS, SUBSTEPS
    lt = x[:7]
    if np.any(lt < LO) or np.any(lt > HI):
        return -np.inf
    lp = -0.5 * np.sum(((lt - PRIOR_MU) / PRIOR_SD) ** 2)
    theta = np.exp(lt)
    for (_, t, gamma, tau), ls in zip(runs, x[7:]):
        if not (0.0 <= ls <= math.log(1e6)):
            return -np.inf
        ss = residual_ss(theta, t, gamma, tau, substeps)
        if not math.isfinite(ss):
            return -np.inf
        lp += -(len(t) - 1) * ls - 0.5 * ss * math.exp(-2.0 * ls)
    return lp


def min_bulk_ess(samples):
    """samples: [chain, draw, 7]"""
    idata = az.from_dict(posterior={n: samples[:, :, i] for i, n in enumerate(NAMES)})
    ess = az.ess(idata, method="bulk")
    return min(float(ess[n]) for n in NAMES)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("campaign", type=pathlib.Path)
    ap.add_argument("--current", type=float, default=1.0)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--substeps", type=int, default=4)
    args = ap.parse_args()
    repo = pathlib.Path(__file__).resolve().parents[2]
    out = args.campaign / "mrbp-calibration"

    # mrbp, as a user runs it
    clock = time.perf_counter()
    # --exact-input: the posterior below (mrbp's default adds the strain's
    # noise to the residuals' variance: errors in variables)
    subprocess.run([str(repo / "target/release/mrbp"), "sample", str(args.campaign / "campaign.toml"),
                    "--current", str(args.current), "--exact-input", "--out", str(out)], check=True, stdout=subprocess.DEVNULL)
    mrbp_seconds = time.perf_counter() - clock
    summary = pd.read_parquet(out / "summary.parquet").set_index("parameter")
    mrbp_ess = summary.loc[NAMES, "ess_bulk"].min()
    record = tomllib.loads((out / "calibration.toml").read_text())

    # emcee + numba on the same posterior, from a ball around mrbp's MAP
    runs = load(args.campaign, args.current)
    rng = np.random.default_rng(1)
    centre = np.array([math.log(record["map"][n]) for n in NAMES] + [math.log(record["map"]["sigma_" + r[0]]) for r in runs])
    spread = np.array([record["laplace_sd_log"][n] for n in NAMES] + [0.02] * len(runs))
    start = centre + 0.5 * spread * rng.standard_normal((args.walkers, len(centre)))
    processes = os.cpu_count()
    setup(runs, args.substeps)
    with multiprocessing.Pool(processes, initializer=setup, initargs=(runs, args.substeps)) as pool:
        pool.map(log_prob, [centre] * processes)  # numba compiles here, outside the clock
        sampler = emcee.EnsembleSampler(args.walkers, len(centre), log_prob, pool=pool)
        clock = time.perf_counter()
        sampler.run_mcmc(start, args.steps)
        emcee_seconds = time.perf_counter() - clock
    chain = sampler.get_chain()[args.steps // 3:]  # [draw, walker, dim]
    emcee_ess = min_bulk_ess(np.exp(np.transpose(chain[:, :, :7], (1, 0, 2))))
    means = np.exp(chain[:, :, :7]).reshape(-1, 7).mean(axis=0)

    print(f"{processes} cores; {len(runs)} runs of {sum(len(r[1]) for r in runs)} samples in all")
    print(f"{'':8} {'seconds':>9} {'min bulk ESS':>13} {'ESS/s':>9}")
    print(f"{'mrbp':8} {mrbp_seconds:9.1f} {mrbp_ess:13.0f} {mrbp_ess / mrbp_seconds:9.2f}")
    print(f"{'emcee':8} {emcee_seconds:9.1f} {emcee_ess:13.0f} {emcee_ess / emcee_seconds:9.2f}")
    print(f"ratio: {(mrbp_ess / mrbp_seconds) / (emcee_ess / emcee_seconds):.0f}x")
    print("posterior means, mrbp vs emcee (sd units of mrbp):")
    for i, n in enumerate(NAMES):
        print(f"  {n:3} {summary.loc[n, 'mean']:.5e} {means[i]:.5e} ({(means[i] - summary.loc[n, 'mean']) / summary.loc[n, 'sd']:+.2f} sd)")


if __name__ == "__main__":
    sys.exit(main())
