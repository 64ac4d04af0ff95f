"""A new test at a current nobody tested, on virtual dampers whose
parameters follow curves in the current of shapes mrbp does not assume.

mrbp's between-run layer reads each B-P parameter's centre off a curve in
the current (a power law with room to bend between the calibrated
currents). Here every damper draws, for each parameter, a shape of its own
from a family the layer does not contain, and the question is whether the
band of `mrbp simulate DIR --new-test --current I` still holds tests at
currents that were not calibrated.

Each damper (docs/comparison.md, "Between the calibrated currents"):

- its B-P parameters at 1 A: the stand's reference values, each times
  exp(N(0, 0.2^2));
- the stresses R0, R1, D1 each on a shape of their own drawn from
  tanh(I/Is) (Is 0.3-1.5 A), a power I^p (p 0.3-1.2), a logistic step
  (centre 0.2-0.9 A, width 0.08-0.3 A, zero at 0 A), a piecewise-linear
  saturation (knee 0.3-1.2 A, slope after it 0-0.3 of the one before) and
  1 - exp(-I/Ie) (Ie 0.2-1 A), with an off-state floor of 2-10 % of the
  1 A value;
- G rising or falling with the current: G(I) = G(1 A) (1 + a (s(I) - 1)),
  s one of the shapes above, a uniform in (-0.6, 0.5) (G at 0 A 0.5-1.6
  times G at 1 A); n the same with a in (-0.25, 0.25); m1, m2 constant;
- tests of the damper differ a little: each record's ln G, ln n and the
  stresses' common ln scale move by N(0, 0.05^2), N(0, 0.02^2), N(0, 0.03^2).

Calibrated at 0.25, 0.5, 1.0 and 1.5 A (crank at 100 and 300 rpm, one
revolution at 2 kHz, 15 N force noise): `mrbp run --per-run`. Then records
at 0.15, 0.375, 0.75, 1.25 and 1.9 A (150 and 350 rpm, speeds not
calibrated either), and for the band's width where nothing is
interpolated at 0.5 and 1.0 A, are predicted as new tests by `mrbp simulate
OUT/I1.0A --input RECORD --new-test --current I`, and the share of each
record's force inside the 95 % band of a measured force (`force_p025_n`,
`force_p975_n`) is written down.

    python scripts/curve_shapes.py MRBP OUT DAMPERS [JOBS]

A damper whose folder already holds complete results (`mrbp status`) is
not calibrated again. Writes OUT/shapes.parquet (damper, shape per
parameter) and OUT/coverage.parquet (damper, run, current_a, rpm, kind:
`between` the calibrated currents, `beyond` them or `calibrated`, inside_p95,
band_width over the record's peak force).
"""
import concurrent.futures as cf, math, os, random, subprocess, sys
import numpy as np
import pandas as pd
from virtual_tests import one_test, synth as write_record

REFERENCE = {"G": 2e5, "R0": 1.2e5, "R1": 1.6e5, "D1": 3e4, "m1": 4e-6, "m2": 2e-4, "n": 1.2}
CALIBRATED = [0.25, 0.5, 1.0, 1.5]
CALIBRATED_RPMS = [100.0, 300.0]
# currents not calibrated, then two calibrated ones (the band's width where
# nothing is interpolated; appended so that the earlier records stay as they were)
TESTED = [0.15, 0.375, 0.75, 1.25, 1.9, 0.5, 1.0]
TESTED_RPMS = [150.0, 350.0]
SHAPES = ["tanh", "power", "logistic", "piecewise", "exponential"]


def shape(rng):
    """A saturation curve s(I) with s(1 A) = 1, drawn from one of SHAPES."""
    kind = rng.choice(SHAPES)
    if kind == "tanh":
        i_s = rng.uniform(0.3, 1.5)
        f = lambda i: math.tanh(i / i_s)
        label = f"tanh(I/{i_s:.2f})"
    elif kind == "power":
        p = rng.uniform(0.3, 1.2)
        f = lambda i: i ** p
        label = f"I^{p:.2f}"
    elif kind == "logistic":
        c, w = rng.uniform(0.2, 0.9), rng.uniform(0.08, 0.3)
        g = lambda i: 1.0 / (1.0 + math.exp(-(i - c) / w))
        f = lambda i: g(i) - g(0.0)
        label = f"logistic(c={c:.2f}, w={w:.2f})"
    elif kind == "piecewise":
        k, slope = rng.uniform(0.3, 1.2), rng.uniform(0.0, 0.3)
        f = lambda i: min(i, k) / k + slope * max(i - k, 0.0) / k
        label = f"knee {k:.2f} A, slope {slope:.2f}"
    else:
        e = rng.uniform(0.2, 1.0)
        f = lambda i: 1.0 - math.exp(-i / e)
        label = f"1-exp(-I/{e:.2f})"
    one = f(1.0)
    return (lambda i: f(i) / one), label


def damper(rng):
    """A virtual damper: its parameters as functions of the current."""
    at_1a = {k: v * math.exp(0.2 * rng.gauss(0, 1)) for k, v in REFERENCE.items()}
    curves, labels = {}, {}
    for k in ("R0", "R1", "D1"):
        s, label = shape(rng)
        floor = rng.uniform(0.02, 0.1)
        curves[k] = (lambda s, floor, v: lambda i: v * (floor + (1 - floor) * s(i)))(s, floor, at_1a[k])
        labels[k] = f"{label}, floor {floor:.2f}"
    for k, (lo, hi) in (("G", (-0.6, 0.5)), ("n", (-0.25, 0.25))):
        s, label = shape(rng)
        a = rng.uniform(lo, hi)
        curves[k] = (lambda s, a, v: lambda i: v * (1 + a * (s(i) - 1)))(s, a, at_1a[k])
        labels[k] = f"1 {a:+.2f} (s-1), s = {label}"
    for k in ("m1", "m2"):
        curves[k] = (lambda v: lambda i: v)(at_1a[k])
        labels[k] = "constant"
    return curves, labels


def test_at(curves, current, rng):
    """One test of the damper at `current`: its parameters, a little off the curves."""
    return one_test({k: c(current) for k, c in curves.items()}, rng, 0.05, 0.02, 0.03)


def record(mrbp, base, run, current, rpm, law, seed):
    # synth's stand at 1 A takes the law as given; the record is then
    # labelled with the current it stands for
    csv = write_record(mrbp, os.path.join(base, run), 1.0, rpm, law, seed)
    t = pd.read_csv(csv)
    if "current_a" in t:
        t["current_a"] = current
        t.to_csv(csv, index=False)
    return csv


MANIFEST_HEAD = 'name = "shapes"\n[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n'


def constant_runs(mrbp, base, r, curves, rng):
    """The damper's calibrated runs (manifest lines) and its records at
    the currents not calibrated, made in `base`."""
    manifest = ""
    for ci, c in enumerate(CALIBRATED):
        for i, rpm in enumerate(CALIBRATED_RPMS):
            run = f"c{ci}r{int(rpm)}"
            csv = record(mrbp, base, run, c, rpm, test_at(curves, c, rng), 11000 + 100 * r + 10 * ci + i)
            manifest += f'[[run]]\nid = "{run}"\nfile = "{csv}"\ncurrent_a = {c}\n'
    tested = []
    for ci, c in enumerate(TESTED):
        for i, rpm in enumerate(TESTED_RPMS):
            run = f"new{ci}r{int(rpm)}"
            csv = record(mrbp, base, run, c, rpm, test_at(curves, c, rng), 21000 + 100 * r + 10 * ci + i)
            tested.append((run, c, rpm, csv))
    return manifest, tested


def one(r):
    rng = random.Random(3000 + r)
    curves, labels = damper(rng)
    base = os.path.join(OUT, f"d{r:03d}")
    manifest, tested = constant_runs(MRBP, base, r, curves, rng)
    with open(os.path.join(base, "campaign.toml"), "w") as f:
        f.write(MANIFEST_HEAD + manifest)
    out = os.path.join(base, "out")
    if subprocess.run([MRBP, "status", out], capture_output=True).returncode != 0:
        done = subprocess.run([MRBP, "run", os.path.join(base, "campaign.toml"), "--out", out, "--per-run",
                               "--substeps", "2", "--draws", "400", "--threads", "1", "--force"], capture_output=True, text=True)
        if done.returncode != 0:
            return r, None, labels, done.stderr[-400:]
    rows = []
    for run, c, rpm, csv in tested:
        sim = os.path.join(base, "sim", run)
        done = subprocess.run([MRBP, "simulate", os.path.join(out, "I1.0A"), "--input", csv, "--new-test",
                               "--current", str(c), "--out", sim, "--threads", "1"], capture_output=True, text=True)
        if done.returncode != 0:
            return r, None, labels, done.stderr[-400:]
        band = pd.read_parquet(os.path.join(sim, "simulation.parquet"))
        y = pd.read_csv(csv)["force_n"].to_numpy()
        lo, hi = band["force_p025_n"].to_numpy(), band["force_p975_n"].to_numpy()
        kind = "calibrated" if c in CALIBRATED else "between" if CALIBRATED[0] < c < CALIBRATED[-1] else "beyond"
        rows.append((r, run, c, rpm, kind, float(np.mean((y >= lo) & (y <= hi))),
                     float(np.mean(hi - lo) / np.max(np.abs(y)))))
    return r, rows, labels, ""


if __name__ == "__main__":
    MRBP, OUT, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
    JOBS = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    rows, shapes = [], []
    with cf.ThreadPoolExecutor(JOBS) as ex:
        for r, got, labels, err in ex.map(one, range(N)):
            shapes += [(r, k, v) for k, v in labels.items()]
            if got is None:
                print(f"damper {r} failed: {err}", flush=True)
                continue
            rows += got
            held = " ".join(f"{c}A:{100 * v:.0f}" for (_, _, c, _, _, v, _) in got)
            print(f"damper {r}: inside the 95 % band (%) {held}", flush=True)
    pd.DataFrame(shapes, columns=["damper", "parameter", "shape"]).to_parquet(os.path.join(OUT, "shapes.parquet"))
    t = pd.DataFrame(rows, columns=["damper", "run", "current_a", "rpm", "kind", "inside_p95", "band_width"])
    t.to_parquet(os.path.join(OUT, "coverage.parquet"))
    for kind in ("between", "beyond", "calibrated"):
        v = t[t["kind"] == kind]
        if len(v) == 0:
            continue
        x = v["inside_p95"]
        print(f"{kind}: {len(v)} records, pooled {100 * x.mean():.1f} % inside; records at 99 % or more "
              f"{100 * (x >= 0.99).mean():.0f} %, 90-99 % {100 * ((x >= 0.9) & (x < 0.99)).mean():.0f} %, "
              f"below 90 % {100 * (x < 0.9).mean():.0f} % (lowest {100 * x.min():.1f} %); band width "
              f"{100 * v['band_width'].median():.0f} % of the peak (median)")
    for c in TESTED:
        v = t[t["current_a"] == c]["inside_p95"]
        if len(v):
            print(f"{c} A: pooled {100 * v.mean():.1f} % inside ({len(v)} records)")
