"""Spencer et al.'s (1997) modified Bouc-Wen model fitted by least squares,
the way practitioners fit it, outside mrbp: the yardstick for mrbp's
Bayesian calibration of the same model (`--law spencer`) on measured
records (docs/real-data.md, "Damper laws on the measured damper").

    python benches/peer/spencer_least_squares.py data/utfsm-mts/campaign.toml [--held-out] [--lag-ms L] [--current I]

For each coil current of the campaign: one parameter set for every
excitation at that current, a parallel spring k1 for the accumulator and a
force offset per test, fitted to the measured force of all its records by
scipy's trust-region least squares (log coordinates for the positive
parameters, several starts, the best kept). The model is the one mrbp
calibrates, in the same normalised Bouc-Wen form,

    F = c1 y' + k1 x + F0,   y' = [fz w + c0 x' + k0 (x - y)] / (c0 + c1),
    w' = rho [u - shape |u| |w|^n sgn w + (shape - 1) u |w|^n],  u = x' - y',

integrated here independently of mrbp: a linearly implicit Euler step
(the 2x2 Jacobian of (y, w) solved at each sub-step; L-stable, as the
loop's reversals are stiff) with 8 sub-steps per sample, compiled by
numba; velocity from the displacement by a Savitzky-Golay derivative
(cubic, about 10 ms wide). The step is checked at the fit: 32 sub-steps
change no record's error by more than the printed amount.

Prints per record the in-sample nRMSE = RMS(F - F_model) / max|F|, and
with --held-out each excitation predicted from a fit to the other three
at its current (its offset the mean of theirs). --lag-ms L pairs each
force sample with the displacement recorded L ms later (a displacement
channel that lags the force channel; linear between samples), as mrbp's
`[likelihood] displacement_lag_ms`.

Needs numpy, scipy, numba (pip).
"""
import argparse
import math
import pathlib
import tomllib

import numba
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

SUBSTEPS = 8
# c0, c1, k0, fz, rho, shape, n: log coordinates
NAMES = ["c0", "c1", "k0", "fz", "rho", "shape", "n"]


@numba.njit(cache=True)
def spencer_force(theta, x, v, dt, substeps):
    """c1 y' along the record (N), from y = x[0], w = 0."""
    c0, c1, k0, fz, rho, shape, n = theta
    inv_c = 1.0 / (c0 + c1)
    y, w = x[0], 0.0
    out = np.empty(x.shape[0])
    h = dt / substeps
    for k in range(x.shape[0]):
        # the force at sample k from the state there
        yd = (fz * w + c0 * v[k] + k0 * (x[k] - y)) * inv_c
        out[k] = c1 * yd
        if k + 1 == x.shape[0]:
            break
        for s in range(substeps):
            # the inputs at the sub-step's start, linear between samples
            xs = x[k] + (s / substeps) * (x[k + 1] - x[k])
            vs = v[k] + (s / substeps) * (v[k + 1] - v[k])
            yd = (fz * w + c0 * vs + k0 * (xs - y)) * inv_c
            u = vs - yd
            aw = abs(w)
            wn = aw ** n
            sg = 1.0 if w > 0 else (-1.0 if w < 0 else 0.0)
            su = 1.0 if u > 0 else (-1.0 if u < 0 else 0.0)
            g = 1.0 - shape * su * sg * wn + (shape - 1.0) * wn
            wd = rho * u * g
            # Jacobian of (y', w') in (y, w)
            dyd_dy = -k0 * inv_c
            dyd_dw = fz * inv_c
            du_dy = -dyd_dy
            du_dw = -dyd_dw
            # dg/dw (away from w = 0 the derivative of |w|^n)
            dwn = n * aw ** (n - 1.0) * sg if aw > 0 else 0.0
            dg_dw = -shape * su * (n * aw ** (n - 1.0) if aw > 0 else 0.0) + (shape - 1.0) * dwn
            j11, j12 = dyd_dy, dyd_dw
            j21 = rho * du_dy * g
            j22 = rho * (du_dw * g + u * dg_dw)
            # (I - h J) d = h f
            a11, a12 = 1.0 - h * j11, -h * j12
            a21, a22 = -h * j21, 1.0 - h * j22
            det = a11 * a22 - a12 * a21
            f1, f2 = h * yd, h * wd
            dy = (f1 * a22 - a12 * f2) / det
            dw = (a11 * f2 - a21 * f1) / det
            y += dy
            w += dw
    return out


def load(manifest, lag_s=0.0):
    root = pathlib.Path(manifest).parent
    spec = tomllib.loads(pathlib.Path(manifest).read_text())
    runs = []
    for r in spec["run"]:
        data = np.genfromtxt(root / r["file"], delimiter=",", names=True)
        t, x, f = data["time_s"], data["displacement_m"], data["force_n"]
        dt = float(np.median(np.diff(t)))
        if lag_s != 0.0:
            # x at t + lag: linear between samples, along the end interval beyond
            shifted = np.interp(t + lag_s, t, x)
            beyond = t + lag_s > t[-1]
            slope = (x[-1] - x[-2]) / (t[-1] - t[-2])
            shifted[beyond] = x[-1] + (t[beyond] + lag_s - t[-1]) * slope
            x = shifted

        window = max(5, int(round(0.010 / dt)) | 1)
        xs = savgol_filter(x, window, 3)
        v = savgol_filter(x, window, 3, deriv=1, delta=dt)
        runs.append(dict(id=r["id"], current=float(r["current_a"]), x=xs, v=v, f=f, dt=dt))
    return runs


def unpack(p, count):
    theta = np.exp(p[:7])
    k1 = p[7]
    offsets = p[8 : 8 + count]
    return theta, k1, offsets


def model(theta, k1, offset, run, substeps=SUBSTEPS):
    return spencer_force(theta, run["x"], run["v"], run["dt"], substeps) + k1 * run["x"] + offset


def fit(runs):
    peak_f = max(np.abs(r["f"]).max() for r in runs)
    peak_v = max(np.abs(r["v"]).max() for r in runs)
    stroke = max(np.ptp(r["x"]) for r in runs)
    scale = [1.0 / math.sqrt(len(r["f"])) for r in runs]

    def residuals(p):
        theta, k1, offsets = unpack(p, len(runs))
        parts = []
        for r, o, s in zip(runs, offsets, scale):
            m = model(theta, k1, o, r)
            parts.append(np.nan_to_num((r["f"] - m) * s, nan=1e6, posinf=1e6, neginf=-1e6))
        return np.concatenate(parts)

    starts = []
    for c0_share, fz_share, rho_stroke, shape, n, c1_ratio, k0 in [
        (0.3, 0.7, 20.0, 0.5, 2.0, 10.0, 1e3),
        (0.1, 0.9, 100.0, 0.5, 1.5, 30.0, 1e4),
        (0.6, 0.4, 5.0, 1.0, 2.0, 5.0, 1e2),
        (0.2, 0.8, 50.0, 0.8, 3.0, 100.0, 3e3),
    ]:
        c0 = c0_share * peak_f / peak_v
        theta = [c0, c1_ratio * c0, k0, fz_share * peak_f, rho_stroke / stroke, shape, n]
        starts.append(np.concatenate([np.log(theta), [0.0], np.zeros(len(runs))]))
    # n >= 1 and the other bounds of mrbp's physical ranges
    lower = np.concatenate([np.log([1e-2, 1.0, 1e-2, 1e-3, 1.0, 1e-3, 1.0]), [-1e6], -np.inf * np.ones(len(runs))])
    upper = np.concatenate([np.log([1e7, 1e8, 1e8, 1e6, 1e8, 1e3, 20.0]), [1e6], np.inf * np.ones(len(runs))])
    best = None
    for p0 in starts:
        p0 = np.clip(p0, lower + 1e-9, upper - 1e-9)
        res = least_squares(residuals, p0, bounds=(lower, upper), x_scale="jac", method="trf", max_nfev=400)
        if best is None or res.cost < best.cost:
            best = res
    return best.x


def nrmse(run, m):
    return math.sqrt(np.mean((run["f"] - m) ** 2)) / np.abs(run["f"]).max()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("manifest")
    ap.add_argument("--held-out", action="store_true")
    ap.add_argument("--lag-ms", type=float, default=0.0)
    ap.add_argument("--current", type=float)
    args = ap.parse_args()
    runs = load(args.manifest, 1e-3 * args.lag_ms)
    currents = sorted({r["current"] for r in runs})
    if args.current is not None:
        currents = [c for c in currents if abs(c - args.current) < 1e-9]
    for c in currents:
        at = [r for r in runs if r["current"] == c]
        p = fit(at)
        theta, k1, offsets = unpack(p, len(at))
        print(f"{c} A: " + ", ".join(f"{n} {v:.4g}" for n, v in zip(NAMES, theta)) + f", k1 {k1:.4g}")
        errors = []
        for r, o in zip(at, offsets):
            e = nrmse(r, model(theta, k1, o, r))
            fine = nrmse(r, model(theta, k1, o, r, 4 * SUBSTEPS))
            errors.append(e)
            print(f"  {r['id']:20s} in-sample nRMSE {100 * e:5.2f} %  (with 4x the sub-steps {100 * fine:5.2f} %)")
        print(f"  mean in-sample nRMSE {100 * np.mean(errors):.2f} %")
        if args.held_out:
            held = []
            for i, r in enumerate(at):
                others = [o for j, o in enumerate(at) if j != i]
                q = fit(others)
                theta_o, k1_o, offsets_o = unpack(q, len(others))
                e = nrmse(r, model(theta_o, k1_o, float(np.mean(offsets_o)), r))
                held.append(e)
                print(f"  {r['id']:20s} held-out nRMSE {100 * e:5.2f} %")
            print(f"  mean held-out nRMSE {100 * np.mean(held):.2f} %")


if __name__ == "__main__":
    main()
