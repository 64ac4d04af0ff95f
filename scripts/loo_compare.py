"""PSIS-LOO of several calibrations of the same records, side by side.

    python scripts/loo_compare.py NAME=FOLDER NAME=FOLDER ...

Each FOLDER is a calibration folder with inference.zarr. Prints ArviZ's
az.compare table (elpd_loo on the log scale: higher predicts better) and
how many observations have a Pareto k above 0.7 in each.
"""

import sys
import warnings

import arviz as az
import xarray as xr


def load(folder):
    return az.InferenceData.from_datatree(xr.open_datatree(f"{folder}/inference.zarr", engine="zarr"))


def main(args):
    if len(args) < 2 or not all("=" in a for a in args):
        sys.exit(__doc__)
    models = {a.split("=", 1)[0]: load(a.split("=", 1)[1]) for a in args}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loos = {name: az.loo(idata, reff=1.0, pointwise=True) for name, idata in models.items()}
        table = az.compare(loos)
    n = next(iter(models.values())).observed_data.sizes["obs"]
    print(table[["rank", "elpd_loo", "p_loo", "elpd_diff", "se", "dse", "weight"]].to_string(float_format=lambda v: f"{v:.1f}"))
    for name, loo in loos.items():
        bad = int((loo.pareto_k.values > 0.7).sum())
        print(f"{name}: elpd_loo per observation {loo.elpd_loo / n:.3f}, Pareto k > 0.7 at {bad} of {n} observations")


if __name__ == "__main__":
    main(sys.argv[1:])
