"""Virtual tests for the coverage studies of the between-run layer
(layer_coverage.py, current_coverage.py): one record of a given B-P law,
written by `mrbp synth` on the bundled stand's geometry (one revolution at
2 kHz, 15 N force noise, 2 µm displacement noise)."""
import math, os, subprocess


def one_test(law, rng, g_sd, n_sd, stresses_sd):
    """A test of a damper whose tests differ: `law` (B-P parameters by
    name) with ln G, ln n and the stresses' common ln scale moved by
    normals of these sds, drawn from `rng` (a random.Random) in that order."""
    law = dict(law)
    law["G"] *= math.exp(g_sd * rng.gauss(0, 1))
    law["n"] *= math.exp(n_sd * rng.gauss(0, 1))
    s = math.exp(stresses_sd * rng.gauss(0, 1))
    for k in ("R0", "R1", "D1"):
        law[k] *= s
    return law

def synth(mrbp, folder, current, rpm, law, seed, noise_force_n=15.0, noise_displacement_m=0.000002):
    """One virtual record of `law` (the B-P parameters at 1 A, stresses
    saturating as tanh(I)) at `current` and `rpm`; returns its path."""
    os.makedirs(folder, exist_ok=True)
    at = "\n".join(f"{k} = {v!r}" for k, v in law.items())
    cfg = f"""name = "t"
currents_a = [{current}]
rpms = [{rpm}]
cycles = 1.0
rate_hz = 2000.0
noise_force_n = {noise_force_n!r}
noise_displacement_m = {noise_displacement_m!r}
seed = {seed}
[geometry]
area_m2 = 0.05
gap_m = 0.001
[crank]
radius_m = 0.00675
rod_m = 0.15
[law]
saturation_a = 1.0
[law.at_1a]
{at}
"""
    with open(os.path.join(folder, "synth.in.toml"), "w") as f:
        f.write(cfg)
    subprocess.run([mrbp, "synth", "--out", folder, "--config", os.path.join(folder, "synth.in.toml")], check=True, capture_output=True)
    return next(os.path.join(folder, n) for n in os.listdir(folder) if n.endswith(".csv"))
