"""How often the validation study ranks the law that made the records first.

For each generating law G and replicate k: `mrbp synth --law G` makes a
virtual campaign (G's typical damper at 1 A, one revolution at 100, 200 and
400 rpm, 2 kHz, 15 N force noise, exact displacement, noise seed 1000 + k),
then `mrbp run --law LAWS --leave-one-out` calibrates every candidate law on
it, holds each record out in turn and names the law that predicts the
held-out records best (its first verdict line, "at 1 A the X law predicts
the held-out tests best: … (… decisive|not decisive …)"). Prints a table:
for each generating law, how often each law was ranked first, and how often
decisively (more than 2 standard errors of held-out log predictive density
ahead of the second).

    python scripts/law_ranking.py MRBP OUT REPLICATES [JOBS] [LAWS] [GENERATING]

LAWS: the candidate laws, comma-separated (default
bingham,bouc-wen,spencer,bodner-partom); GENERATING: the laws whose
records are made (default: LAWS).

Every law is calibrated with independent residuals (`--memory
independent`), as the study was first run (the default, `auto`, would
allow for the memory a wrong law leaves in its residuals, and does not
for the generating law's white ones): the ranking compares the laws under
one likelihood.

Standard library only. A replicate whose verdict is already in OUT is not
run again; one stopped half-way is run again from the start. Writes OUT/ranking.csv (generating, replicate, first, decisive).
"""
import concurrent.futures as cf, csv, os, re, subprocess, sys

MRBP, OUT, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
JOBS = int(sys.argv[4]) if len(sys.argv) > 4 else 1
LAWS = (sys.argv[5].split(",") if len(sys.argv) > 5
        else ["bingham", "bouc-wen", "spencer", "bodner-partom"])
GENERATING = sys.argv[6].split(",") if len(sys.argv) > 6 else LAWS
VERDICT = re.compile(r"at 1 A the (\S+) law predicts the held-out tests best.*?\b(not decisive|decisive)\b")


def replicate(generating, k):
    folder = os.path.join(OUT, generating, f"r{k:03d}")
    verdict_file = os.path.join(folder, "verdict.txt")
    if os.path.exists(verdict_file):
        return generating, k, open(verdict_file).read().strip()
    data = os.path.join(folder, "data")
    threads = str(max(1, (os.cpu_count() or 2) // JOBS))
    subprocess.run(
        [MRBP, "synth", "--out", data, "--law", generating, "--currents", "1.0",
         "--cycles", "1", "--rate", "2000", "--noise-displacement", "0",
         "--seed", str(1000 + k), "--threads", threads],
        check=True, capture_output=True)
    run = subprocess.run(
        [MRBP, "run", os.path.join(data, "campaign.toml"), "--law", ",".join(LAWS),
         "--leave-one-out", "--draws", "100", "--out", os.path.join(folder, "out"), "--force",
         "--memory", "independent", "--threads", threads],
        capture_output=True, text=True)
    said = run.stdout + run.stderr
    found = VERDICT.search(said)
    if run.returncode != 0 or not found:
        raise RuntimeError(f"{generating} r{k}: exit {run.returncode}\n{said[-2000:]}")
    line = f"{found.group(1)} {found.group(2)}"
    with open(verdict_file, "w") as f:
        f.write(line + "\n")
    return generating, k, line


def main():
    os.makedirs(OUT, exist_ok=True)
    # replicate by replicate, so that a study cut short holds every law alike
    jobs = [(g, k) for k in range(N) for g in GENERATING]
    rows = []
    with cf.ThreadPoolExecutor(JOBS) as pool:
        for generating, k, line in pool.map(lambda j: replicate(*j), jobs):
            first, decisive = line.split(" ", 1)
            rows.append((generating, k, first, decisive == "decisive"))
            print(f"{generating} r{k:03d}: {line}", flush=True)
    with open(os.path.join(OUT, "ranking.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["generating", "replicate", "first", "decisive"])
        w.writerows(rows)
    print("\n| records of | " + " | ".join(f"{l} first" for l in LAWS) + " | decisive |")
    print("|---" * (len(LAWS) + 2) + "|")
    for g in GENERATING:
        mine = [r for r in rows if r[0] == g]
        counts = [sum(r[2] == l for r in mine) for l in LAWS]
        decisive = sum(r[3] for r in mine if r[2] == g)
        print(f"| {g} | " + " | ".join(f"{c}/{len(mine)}" for c in counts) + f" | {decisive}/{len(mine)} |")


main()
