"""Through a switch: bands for a run whose coil current is switched, on the
virtual dampers of curve_shapes.py (parameters on curves in the current of
shapes mrbp does not assume) with a coil lag of their own.

The switched records are made here, not by `mrbp synth`: the B-P shear law
(the flow rule, the hardening, tau' = G (gamma' - gamma_I'),
W' = tau gamma_I') is integrated by scipy's Radau method with
tight tolerances, the parameters taken at the field current I_f, which
trails the commanded current as dI_f/dt = (I - I_f) / tau_c; the state
(tau, W) carries through every switch. At a constant current the same
integration is checked against `mrbp synth` (printed: RMS difference of
the noiseless force, in N).

Each damper (the first DAMPERS of curve_shapes.py's, same seeds):
- tau_c uniform in 5-30 ms;
- a switched run: the crank at 200 rpm for two revolutions (0.6 s at 2 kHz,
  15 N force noise), the current commanded between 0.375 and 1.25 A (two
  currents no constant run had), switched every 0.1 s;
- current curves (`mrbp sample --model current-curves`) calibrated on the
  eight constant-current runs alone: the switched run simulated from them
  (`mrbp simulate`, the lag from its prior), the share of it inside the
  95 % band of a measured force;
- current curves calibrated on the constant runs and one more switched run
  (250 rpm, another record of the same damper): does the coil lag's 90 %
  interval hold tau_c; and the first switched run simulated from them.
- how many steps each calibration ran, and at which step R-hat < 1.01,
  ESS >= 400 and 10 tau first held (calibration.toml's
  first_converged_step).

    python scripts/switch_lag.py MRBP OUT DAMPERS [JOBS] [FIRST]

Dampers FIRST to FIRST + DAMPERS - 1 (FIRST 0 by default). Writes
OUT/switch.parquet, or OUT/switch-FIRST.parquet where FIRST is given
(damper, tau_c_ms, calibration, inside_p95, lag_q05_ms, lag_q50_ms,
lag_q95_ms, steps, first_held).
"""
import concurrent.futures as cf, math, os, random, subprocess, sys, tomllib
import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp
import curve_shapes as shapes

D0 = 1e4
AREA, GAP = 0.05, 0.001
CRANK_R, CRANK_L = 0.00675, 0.15
RATE = 2000.0
NOISE_N, NOISE_X = 15.0, 2e-6
LEVELS = (0.375, 1.25)
HOLD_S = 0.1


def crank(rpm, t):
    """Displacement and velocity of the stand's crank from bottom dead centre."""
    th = 2 * math.pi * rpm / 60 * t
    s, c = math.sin(th), math.cos(th)
    root = math.sqrt(CRANK_L ** 2 - (CRANK_R * s) ** 2)
    x = CRANK_R * (1 - c) + CRANK_L - root
    v = 2 * math.pi * rpm / 60 * CRANK_R * s * (1 + CRANK_R * c / root)
    return x, v


def stress(curves, rpm, times, command, tau_c, field0):
    """The B-P shear stress along the crank's strain, the parameters at the
    lagging field current; `command(t)` is constant on [k HOLD_S, (k+1) HOLD_S)."""
    def rhs(t, y, i_cmd):
        tau, w, i_f = y
        p = {k: f(i_f) for k, f in curves.items()}
        _, v = crank(rpm, t)
        gdot = v / GAP
        r = p["R1"] * (1 - math.exp(-p["m1"] * w)) + p["R0"] * math.exp(-p["m1"] * w)
        d = p["D1"] * (1 - math.exp(-p["m2"] * w))
        if tau == 0.0:
            gi = 0.0
        else:
            z = ((r + d) / (math.sqrt(3) * abs(tau))) ** (2 * p["n"]) * (p["n"] + 1) / p["n"]
            gi = 2 * D0 * math.exp(-0.5 * z) * math.copysign(1.0, tau) if z < 1400 else 0.0
        return [p["G"] * (gdot - gi), tau * gi, (i_cmd - i_f) / tau_c]

    out = np.empty(len(times))
    y = [0.0, 0.0, field0]
    edges = sorted(set([0.0] + [k * HOLD_S for k in range(1, int(times[-1] / HOLD_S) + 1)] + [times[-1]]))
    for a, b in zip(edges[:-1], edges[1:]):
        at = [i for i, t in enumerate(times) if a <= t <= b]
        sol = solve_ivp(rhs, (a, b), y, method="Radau", t_eval=[times[i] for i in at], args=(command(a),),
                        rtol=1e-9, atol=[1e-3, 1e-3, 1e-9], max_step=1 / RATE)
        if not sol.success:
            raise RuntimeError(sol.message)
        out[at] = sol.y[0]
        y = sol.y[:, -1] if sol.t[-1] == b else solve_ivp(rhs, (sol.t[-1], b), sol.y[:, -1], method="Radau",
                                                          args=(command(a),), rtol=1e-9, atol=[1e-3, 1e-3, 1e-9]).y[:, -1]
    return out


def switched_record(path, curves, rpm, revolutions, tau_c, seed):
    """A switched run's CSV: time, noisy displacement and force, commanded current."""
    n = int(round(revolutions * 60 / rpm * RATE))
    times = np.arange(n) / RATE
    command = lambda t: LEVELS[int(round(t / HOLD_S, 9)) % 2]
    tau = stress(curves, rpm, times, command, tau_c, LEVELS[0])
    rng = np.random.default_rng(seed)
    x = np.array([crank(rpm, t)[0] for t in times])
    pd.DataFrame({"time_s": times, "displacement_m": x + rng.normal(0, NOISE_X, n),
                  "force_n": tau * AREA + rng.normal(0, NOISE_N, n),
                  "current_a": [command(t) for t in times]}).to_csv(path, index=False)
    return path


def check_against_synth(mrbp, folder, curves, current=0.75, rpm=200.0):
    """RMS difference (N) of this integration and `mrbp synth`'s at a
    constant current, both noiseless."""
    law = {k: f(current) for k, f in curves.items()}
    csv = shapes.write_record(mrbp, folder, 1.0, rpm, law, 1, noise_force_n=0.0, noise_displacement_m=0.0)
    t = pd.read_csv(csv)
    ours = stress(curves, rpm, t["time_s"].to_numpy(), lambda _: current, 1e-6, current) * AREA
    return float(np.sqrt(np.mean((t["force_n"].to_numpy() - ours) ** 2)))


def diagnostics(folder):
    """Steps run, and the step at which R-hat < 1.01, ESS >= 400 and 10 tau
    first held (calibration.toml)."""
    with open(os.path.join(folder, "calibration.toml"), "rb") as f:
        rec = tomllib.load(f)
    return rec["steps"], rec.get("first_converged_step")


def inside(sim, csv):
    band = pd.read_parquet(os.path.join(sim, "simulation.parquet"))
    y = pd.read_csv(csv)["force_n"].to_numpy()
    return float(np.mean((y >= band["force_p025_n"].to_numpy()) & (y <= band["force_p975_n"].to_numpy())))


def one(r):
    rng = random.Random(3000 + r)
    curves, _ = shapes.damper(rng)
    base = os.path.join(OUT, f"d{r:03d}")
    os.makedirs(base, exist_ok=True)
    manifest, _ = shapes.constant_runs(MRBP, base, r, curves, rng)
    tau_c = random.Random(5000 + r).uniform(0.005, 0.03)
    test = switched_record(os.path.join(base, "switched_200rpm.csv"), curves, 200.0, 2, tau_c, 31000 + r)
    extra = switched_record(os.path.join(base, "switched_250rpm.csv"), curves, 250.0, 2, tau_c, 32000 + r)
    rows = []
    for name, lines in (("constant currents", ""),
                        ("with a switched run", f'[[run]]\nid = "switched"\nfile = "{extra}"\ncurrent_a = {LEVELS[1]}\ncurrent_varies = true\n')):
        tag = "constant" if not lines else "switched"
        path = os.path.join(base, f"{tag}.toml")
        with open(path, "w") as f:
            f.write(shapes.MANIFEST_HEAD + manifest + lines)
        folder = os.path.join(base, f"curves-{tag}")
        if subprocess.run([MRBP, "status", folder], capture_output=True).returncode != 0:
            done = subprocess.run([MRBP, "sample", path, "--model", "current-curves", "--out", folder, "--substeps", "2",
                                   "--threads", "1", "--force"], capture_output=True, text=True)
            if done.returncode != 0:
                return r, None, done.stderr[-400:]
        sim = os.path.join(base, f"sim-{tag}")
        done = subprocess.run([MRBP, "simulate", folder, "--input", test, "--out", sim, "--threads", "1"],
                              capture_output=True, text=True)
        if done.returncode != 0:
            return r, None, done.stderr[-400:]
        lag = [math.nan] * 3
        if lines:
            s = pd.read_parquet(os.path.join(folder, "summary.parquet"))
            row = s[s["parameter"] == "coil_lag_s"].iloc[0]
            lag = [1e3 * row[q] for q in ("q05", "q50", "q95")]
        steps, first = diagnostics(folder)
        rows.append((r, 1e3 * tau_c, name, inside(sim, test), *lag, steps, first))
    return r, rows, ""


if __name__ == "__main__":
    MRBP, OUT, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
    JOBS = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    FIRST = int(sys.argv[5]) if len(sys.argv) > 5 else 0
    rng = random.Random(3000)
    curves, _ = shapes.damper(rng)
    print(f"this integration against mrbp synth at 0.75 A: RMS difference {check_against_synth(MRBP, os.path.join(OUT, 'check'), curves):.2f} N (synth's force noise 15 N)", flush=True)
    rows = []
    with cf.ThreadPoolExecutor(JOBS) as ex:
        for r, got, err in ex.map(one, range(FIRST, FIRST + N)):
            if got is None:
                print(f"damper {r} failed: {err}", flush=True)
                continue
            rows += got
            for row in got:
                print(f"damper {r} (tau_c {row[1]:.1f} ms), {row[2]}: {100 * row[3]:.1f} % inside; lag 90 % "
                      f"[{row[4]:.1f}, {row[6]:.1f}] ms; steps {row[7]}, first held {row[8]}", flush=True)
    t = pd.DataFrame(rows, columns=["damper", "tau_c_ms", "calibration", "inside_p95", "lag_q05_ms", "lag_q50_ms",
                                    "lag_q95_ms", "steps", "first_held"])
    t.to_parquet(os.path.join(OUT, f"switch-{FIRST}.parquet" if len(sys.argv) > 5 else "switch.parquet"))
    for name in t["calibration"].unique():
        v = t[t["calibration"] == name]
        print(f"{name}: pooled {100 * v['inside_p95'].mean():.1f} % inside over {len(v)} switched runs "
              f"(lowest {100 * v['inside_p95'].min():.1f} %)")
    w = t[t["calibration"] == "with a switched run"]
    if len(w):
        held = ((w["lag_q05_ms"] <= w["tau_c_ms"]) & (w["tau_c_ms"] <= w["lag_q95_ms"])).mean()
        print(f"the lag's 90 % interval holds tau_c in {100 * held:.0f} % of {len(w)} dampers")
