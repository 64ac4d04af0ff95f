"""How much of a held-out record a 95 % band for a new test holds, on virtual
dampers whose tests differ by a known population: the between-run layer's
band beside the exact band of that population.

Each replicate is one virtual damper tested at 0.5, 1.0 and 1.5 A, four
tests per current (100-400 rpm, one revolution at 2 kHz, 15 N force noise),
every test with its own G, n and stress level: ln G ~ N(ln 2e5, 0.3^2),
ln n ~ N(ln 1.2, 0.1^2), and R0, R1, D1 scaled together by exp(N(0, 0.1^2));
between currents the stresses follow the stand's saturation tanh(I)/tanh(1 A).

- The layer: `mrbp run --per-run --leave-one-out`, read from each current's
  loo_new_test.parquet: each record predicted as a new test by the layer
  fitted without it (left_out = run) and without its whole current
  (left_out = current: the centre read off the curve in the current).
- The exact band (no calibration involved): K tests drawn from the true
  population and simulated by `mrbp synth` at the record's current and
  excitation, noise included; the band is their 2.5 and 97.5 % quantiles
  at each sample. It is what a calibration that knew the population would
  give, the best any band for a new test can do.

Pooled over many tests a right band holds 95 % of the samples. One record
is another matter: where the tests differ by more than the noise, a test is
inside nearly everywhere or, if its own parameters lie in the population's
tails, outside over most of its cycle.

    python scripts/current_coverage.py MRBP OUT REPLICATES [JOBS] [K]

A replicate whose folder already holds complete results (`mrbp status`) is
not calibrated again. Writes OUT/coverage.parquet (replicate, run,
current_a, band, inside_p95).
"""
import concurrent.futures as cf, os, random, subprocess, sys
import numpy as np
import polars as pl
from virtual_tests import one_test, synth as write_record

MRBP, OUT, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
JOBS = int(sys.argv[4]) if len(sys.argv) > 4 else 2
K = int(sys.argv[5]) if len(sys.argv) > 5 else 200
TRUTH = {"G": 2e5, "R0": 1.2e5, "R1": 1.6e5, "D1": 3e4, "m1": 4e-6, "m2": 2e-4, "n": 1.2}
CURRENTS = [0.5, 1.0, 1.5]
RPMS = [100.0, 200.0, 300.0, 400.0]

def test_law(rng):
    """A test drawn from the population."""
    return one_test(TRUTH, rng, 0.3, 0.1, 0.1)

def force(csv):
    return pl.read_csv(csv)["force_n"].to_numpy()

def replicate(r):
    rng = random.Random(2000 + r)
    base = os.path.join(OUT, f"r{r:03d}")
    manifest = 'name = "population"\n[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n'
    records = {}
    for ci, c in enumerate(CURRENTS):
        for i, rpm in enumerate(RPMS):
            run = f"c{int(c * 10):02d}t{i}"
            csv = write_record(MRBP, os.path.join(base, run), c, rpm, test_law(rng), 9000 + 100 * r + 10 * ci + i)
            records[run] = (c, rpm, csv)
            manifest += f'[[run]]\nid = "{run}"\nfile = "{csv}"\ncurrent_a = {c}\n'
    with open(os.path.join(base, "campaign.toml"), "w") as f:
        f.write(manifest)
    out = os.path.join(base, "out")
    done = subprocess.run([MRBP, "status", out], capture_output=True)
    if done.returncode != 0:
        done = subprocess.run([MRBP, "run", os.path.join(base, "campaign.toml"), "--out", out, "--per-run", "--leave-one-out",
                               "--substeps", "2", "--draws", "400", "--threads", "1", "--force"], capture_output=True, text=True)
        if done.returncode != 0:
            return r, None, done.stderr[-400:]
    rows = []
    for c in CURRENTS:
        t = pl.read_parquet(os.path.join(out, f"I{c:.1f}A", "loo_new_test.parquet"))
        for row in t.iter_rows(named=True):
            rows.append((r, row["run"], c, f"layer, {row['left_out']} left out", row["inside_p95"]))
    # the exact band: K tests of the true population at each record's excitation
    population = random.Random(777 + r)
    for run, (c, rpm, csv) in records.items():
        sims = np.array([force(write_record(MRBP, os.path.join(base, "exact", run), c, rpm, test_law(population), 50000 + k)) for k in range(K)])
        lo, hi = np.quantile(sims, [0.025, 0.975], axis=0)
        y = force(csv)
        rows.append((r, run, c, "exact population band", float(np.mean((y >= lo) & (y <= hi)))))
    return r, rows, ""

if __name__ == "__main__":
    rows = []
    with cf.ThreadPoolExecutor(JOBS) as ex:
        for r, got, err in ex.map(replicate, range(N)):
            if got is None:
                print(r, "failed:", err, flush=True)
                continue
            rows += got
            exact = " ".join(f"{100 * v:.0f}" for (_, _, _, b, v) in got if b.startswith("exact"))
            print(f"replicate {r}: exact band holds {exact} % of the twelve records", flush=True)
    t = pl.DataFrame(rows, schema=["replicate", "run", "current_a", "band", "inside_p95"], orient="row")
    t.write_parquet(os.path.join(OUT, "coverage.parquet"))
    for band in sorted(t["band"].unique()):
        v = t.filter(pl.col("band") == band)["inside_p95"]
        print(f"{band}: {len(v)} records, pooled {100 * v.mean():.1f} % inside; records at 99 % or more: {100 * (v >= 0.99).mean():.0f} %, "
              f"in 90-99 %: {100 * ((v >= 0.9) & (v < 0.99)).mean():.0f} %, below 90 %: {100 * (v < 0.9).mean():.0f} % (lowest {100 * v.min():.1f} %)")
