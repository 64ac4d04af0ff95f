"""What an ArviZ user does with a calibration folder, checked.

    python scripts/arviz_check.py CALIBRATION_FOLDER

Opens inference.zarr with xarray and ArviZ as the README says, and checks
that az.summary gives the numbers of summary.parquet, that az.plot_trace
draws, that the ensemble R-hat
recipe of the README gives mrbp's R-hat, that az.loo runs on the pointwise
log-likelihood, and that the replicated records and the observed data are
those of bands.parquet. Exits non-zero with a message on the first miss.
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display in CI
import arviz as az  # noqa: E402
import numpy as np
import pandas as pd
import xarray as xr


def ensemble_rhat(idata):
    """mrbp's R-hat: each ensemble's draws, step by step, as one chain."""
    p = idata.posterior
    e = int(p.ensemble.max()) + 1
    return {v: float(az.rhat(p[v].values.reshape(e, -1, p.sizes["draw"]).transpose(0, 2, 1).reshape(e, -1)))
            for v in p.data_vars}


def tail_ess(x):
    """ArviZ's tail ESS (the smaller of the split-chain ESS of the 5 % and
    95 % quantiles' indicators) with numpy's type-7 quantile. ArviZ takes the
    quantile from scipy's mquantiles, (1 - g) a + g b, which between two tied
    draws (a = b: a rejected proposal repeats a walker's position) can land
    one ulp below them and so leave the tied draws out of the indicator;
    numpy's a + g (b - a), like mrbp's, is exact there."""
    from arviz.stats.diagnostics import _ess, _split_chains
    return min(_ess(_split_chains((x <= np.quantile(x, p)).astype(float))) for p in (0.05, 0.95))


def close(a, b, rel, what):
    if not abs(a - b) <= rel * max(abs(a), abs(b), 1e-300):
        sys.exit(f"{what}: ArviZ {a!r} vs mrbp {b!r} (tolerance {rel:.0e} relative)")


def main(folder):
    folder = Path(folder)
    # the README's loader
    idata = az.InferenceData.from_datatree(xr.open_datatree(folder / "inference.zarr", engine="zarr"))
    for group in ["posterior", "sample_stats", "log_likelihood", "posterior_predictive", "observed_data"]:
        if group not in idata.groups():
            sys.exit(f"inference.zarr lacks the group {group}: {idata.groups()}")

    # az.summary against summary.parquet: same draws, same estimators
    ours = pd.read_parquet(folder / "summary.parquet").set_index("parameter")
    theirs = az.summary(idata, round_to="none")
    rhat = ensemble_rhat(idata)
    for name, row in ours.iterrows():
        t = theirs.loc[name]
        close(t["mean"], row["mean"], 1e-9, f"{name} mean")
        close(t["sd"], row["sd"], 1e-9, f"{name} sd")
        # ESS and MCSE: the same estimators on the same draws (agree to ~1e-14)
        close(t["ess_bulk"], row["ess_bulk"], 1e-9, f"{name} ess_bulk")
        close(tail_ess(idata.posterior[name].values), row["ess_tail"], 1e-9, f"{name} ess_tail")
        close(t["mcse_mean"], row["mcse_mean"], 1e-9, f"{name} mcse_mean")
        close(rhat[name], row["r_hat"], 1e-9, f"{name} ensemble R-hat")

    # az.plot_trace draws every B-P parameter (a figure that can be saved)
    axes = az.plot_trace(idata, var_names=["G", "R0", "n"], compact=True)
    if axes.shape != (3, 2):
        sys.exit(f"az.plot_trace gave axes of shape {axes.shape}")
    axes[0, 0].figure.savefig(folder / "arviz_trace_check.png")
    (folder / "arviz_trace_check.png").unlink()

    # az.loo on the pointwise log-likelihood (thinned, nearly independent draws)
    loo = az.loo(idata, reff=1.0, pointwise=True)
    n_obs = idata.observed_data.sizes["obs"]
    if not np.isfinite(loo.elpd_loo) or loo.loo_i.size != n_obs:
        sys.exit(f"az.loo: elpd {loo.elpd_loo}, {loo.loo_i.size} pointwise values for {n_obs} observations")
    # the pointwise terms are densities of shear stress: elpd per sample is
    # about -ln(sigma sqrt(2 pi e)) for a model that fits to the noise
    sigma = np.mean([float(idata.posterior[v].mean()) for v in idata.posterior.data_vars if v.startswith("sigma_")])
    per_sample = loo.elpd_loo / n_obs
    expected = -np.log(sigma * np.sqrt(2 * np.pi * np.e))
    if not abs(per_sample - expected) < 0.5:
        sys.exit(f"elpd per sample {per_sample:.3f} nat, a fit to the noise gives {expected:.3f}")

    # observed data and replicates against bands.parquet
    bands = pd.read_parquet(folder / "bands.parquet")
    obs = idata.observed_data
    for run in np.unique(obs.run.values):
        mine = obs.tau.values[obs.run.values == run]
        theirs_obs = bands.loc[bands.run == run, "tau_obs"].values[1:]
        if not np.allclose(mine, theirs_obs[: len(mine)], rtol=0, atol=1e-9):
            sys.exit(f"observed_data of {run} differs from bands.parquet")
    rep = idata.posterior_predictive.tau.values.reshape(-1, n_obs)
    lo, hi = np.quantile(rep, [0.025, 0.975], axis=0)
    inside = np.mean((obs.tau.values >= lo) & (obs.tau.values <= hi))
    if not 0.85 <= inside <= 0.995:
        sys.exit(f"{inside:.3f} of the observations inside the replicates' 95 % band")

    print(f"ok: az.summary matches summary.parquet for {len(ours)} coordinates; "
          f"az.loo elpd {loo.elpd_loo:.1f} over {n_obs} observations (p_loo {loo.p_loo:.1f}); "
          f"{inside:.1%} of the observations inside the replicates' 95 % band")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
