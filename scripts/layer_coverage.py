"""Coverage of the between-run layer's new-test intervals on virtual tests
whose parameters vary from test to test by a known population.

Each replicate: five tests of one virtual damper at 1 A, each with its own
G and n (ln G ~ N(ln 2e5, 0.3²), ln n ~ N(ln 1.2, 0.1²); the other B-P
parameters shared), the first four calibrated (`mrbp sample --per-run`,
crank speeds 100-400 rpm, one revolution at 2 kHz), the fifth the new test:
does the layer's 90 % interval for a new test hold its G and n, and the
shared parameters' truth?

    python scripts/layer_coverage.py MRBP OUT REPLICATES [JOBS]
"""
import concurrent.futures as cf, math, os, random, subprocess, sys
import polars as pl
from virtual_tests import synth as write_record

MRBP, OUT, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
JOBS = int(sys.argv[4]) if len(sys.argv) > 4 else 2
TRUTH = {"G": 2e5, "R0": 1.2e5, "R1": 1.6e5, "D1": 3e4, "m1": 4e-6, "m2": 2e-4, "n": 1.2}
SPREAD = {"G": 0.3, "n": 0.1}
RPMS = [100.0, 200.0, 300.0, 400.0]

def replicate(r):
    rng = random.Random(1000 + r)
    tests = []
    for i in range(5):
        law = dict(TRUTH)
        for k, s in SPREAD.items():
            law[k] = TRUTH[k] * math.exp(s * rng.gauss(0, 1))
        tests.append(law)
    base = os.path.join(OUT, f"r{r:03d}")
    manifest = 'name = "population"\n[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n'
    for i, rpm in enumerate(RPMS):
        csv = write_record(MRBP, os.path.join(base, f"t{i}"), 1.0, rpm, tests[i], 7000 + 10 * r + i)
        manifest += f'[[run]]\nid = "t{i}"\nfile = "{csv}"\ncurrent_a = 1.0\n'
    with open(os.path.join(base, "campaign.toml"), "w") as f:
        f.write(manifest)
    out = os.path.join(base, "out")
    done = subprocess.run([MRBP, "sample", os.path.join(base, "campaign.toml"), "--out", out, "--per-run", "--substeps", "2", "--threads", "1", "--force"], capture_output=True, text=True)
    if done.returncode != 0:
        return r, None, done.stderr[-300:]
    table = pl.read_parquet(os.path.join(out, "consistency.parquet")).filter(pl.col("kind") == "new test")
    held = {}
    for row in table.iter_rows(named=True):
        truth = tests[4][row["parameter"]]
        held[row["parameter"]] = (row["q05"] <= truth <= row["q95"], row["q05"], row["q95"], truth)
    layer = [l for l in done.stderr.splitlines() if "between-run layer:" in l]
    return r, held, layer[0] if layer else ""

if __name__ == "__main__":
    results = []
    with cf.ThreadPoolExecutor(JOBS) as ex:
        for r, held, note in ex.map(replicate, range(N)):
            results.append((r, held))
            print(r, "failed" if held is None else " ".join(f"{k}:{int(v[0])}" for k, v in held.items()), note[-80:], flush=True)
    ok = [h for _, h in results if h]
    print(f"{len(ok)} of {N} replicates")
    for k in TRUTH:
        hits = [h[k][0] for h in ok if k in h]
        p = sum(hits) / len(hits)
        print(f"{k:3} 90 % interval holds a new test's value in {100*p:.0f} % (binomial se {100*math.sqrt(0.09/len(hits)):.0f} %)")
