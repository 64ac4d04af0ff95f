"""The Python package against the command line: the same chains at the
same seed, folders each reads of the other, clear exceptions.

Run by ``cargo test --release`` (tests/python.rs), which passes the
command line's binary as MRBP_BIN; by hand: ``pip install ./python`` then
``MRBP_BIN=target/release/mrbp pytest python/tests``.
"""

import os
import signal
import subprocess
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import mrbp

ROOT = Path(__file__).resolve().parents[2]
BIN = os.environ.get("MRBP_BIN", str(ROOT / "target" / "release" / "mrbp"))
MANIFEST = ROOT / "data" / "campaign.toml"

# a short run: 40 steps of the bundled 1 A runs (a few seconds)
OPTIONS = dict(current=1.0, seed=3, steps=40)


def cli(*args):
    done = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return done


@pytest.fixture(scope="module")
def campaign():
    return mrbp.Campaign.load(MANIFEST)


@pytest.fixture(scope="module")
def calibration(campaign):
    return mrbp.calibrate(campaign, **OPTIONS)


def test_same_chains_as_the_command_line(calibration, tmp_path):
    cli("sample", MANIFEST, "--out", tmp_path, "--current", 1.0, "--seed", 3, "--steps", 40)
    chains = pd.read_parquet(tmp_path / "chains.parquet")
    draws = calibration.draws
    assert list(draws.columns) == list(chains.columns)
    # bit for bit: the same values, not merely close ones
    pd.testing.assert_frame_equal(draws, chains, check_exact=True, check_dtype=False)
    summary = pd.read_parquet(tmp_path / "summary.parquet")
    pd.testing.assert_frame_equal(calibration.summary, summary[calibration.summary.columns], check_exact=True)


def test_saved_folder_is_the_command_lines(calibration, tmp_path):
    folder = tmp_path / "I1.0A"
    calibration.save(folder)
    assert calibration.folder == folder
    # the command line predicts from it, and says it is complete
    cli("predict", folder, "--draws", 20, "--replicates", 2)
    cli("status", folder)
    again = mrbp.load(folder)
    assert again.calibration_id == calibration.calibration_id
    pd.testing.assert_frame_equal(again.draws, calibration.draws, check_exact=True)
    with pytest.raises(ValueError, match="already holds results"):
        calibration.save(folder)


def test_frames_calibrate_as_the_files_do(campaign, calibration):
    from_disk = [r for r in campaign.runs if r.startswith("I1.0_")]
    frames = {r: pd.read_csv(MANIFEST.parent / f"{r}.csv") for r in from_disk}
    made = mrbp.Campaign.from_frames(frames, currents={r: 1.0 for r in from_disk}, geometry=(0.05, 1.0e-3), name="frames")
    assert made.runs == from_disk and made.currents == [1.0]
    again = mrbp.calibrate(made, **OPTIONS)
    pd.testing.assert_frame_equal(again.draws, calibration.draws, check_exact=True)


def frame(n=50):
    t = np.linspace(0.0, 0.5, n)
    return pd.DataFrame({"time_s": t, "displacement_m": 0.01 * np.sin(2 * np.pi * 2 * t), "force_n": 100.0 * np.cos(2 * np.pi * 2 * t)})


@pytest.mark.parametrize(
    "spoil, message",
    [
        (lambda f: f.assign(force_n=f.force_n.where(f.index != 4)), r"run 'a', row 5, column 'force_n'.*not a finite number"),
        (lambda f: f.drop(columns="displacement_m"), r"run 'a', column 'displacement_m': no such column"),
        (lambda f: f.assign(time_s=f.time_s.where(f.index != 9, 0.0)), r"run 'a', row 10, column 'time_s'.*does not increase"),
        (lambda f: f.head(5), r"run 'a'.*at least 10"),
        (lambda f: f.assign(force_n=f.force_n * 1e6), r"run 'a', row \d+, column 'force_n'.*beyond the plausible"),
    ],
)
def test_bad_frames_raise_naming_run_row_and_column(spoil, message):
    with pytest.raises(ValueError, match=message):
        mrbp.Campaign.from_frames({"a": spoil(frame())}, currents={"a": 1.0}, geometry=(0.05, 1e-3))


def test_bad_options_raise(campaign):
    with pytest.raises(ValueError, match="say which to calibrate"):
        mrbp.calibrate(campaign, seed=1, steps=10)
    with pytest.raises(ValueError, match='noise "white": one of gaussian'):
        mrbp.calibrate(campaign, current=1.0, noise="white", steps=10)
    with pytest.raises(ValueError, match="the campaign has runs at"):
        mrbp.calibrate(campaign, current=2.0, steps=10)
    with pytest.raises(ValueError, match="manifest not found"):
        mrbp.Campaign.load(ROOT / "no-such.toml")


def test_ctrl_c_raises_keyboard_interrupt(campaign):
    # SIGINT to this process while it samples (released GIL): the sampler
    # stops at its next step and Python sees KeyboardInterrupt
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            mrbp.calibrate(campaign, current=1.0, seed=1, steps=100_000)
    finally:
        timer.cancel()


def test_simulate_equals_the_command_line(calibration, tmp_path):
    # a 5 mm, 3 Hz sine the calibration never saw, without a force
    t = np.arange(0, 701) / 1000.0
    x = 0.005 * np.sin(2 * np.pi * 3.0 * t)
    pd.DataFrame({"time_s": t, "displacement_m": x}).to_csv(tmp_path / "sine.csv", index=False)
    folder = tmp_path / "cal"
    calibration.save(folder)
    for draws in (1, 40):
        out = tmp_path / f"sim{draws}"
        cli("simulate", folder, "--input", tmp_path / "sine.csv", "--out", out, "--draws", draws, "--replicates", 5, "--predict-seed", 7)
        expected = pd.read_parquet(out / "simulation.parquet")
        got = calibration.simulate(t, x, draws=draws, replicates=5, seed=7)
        # the CSV's decimal text reads back to the same doubles
        pd.testing.assert_frame_equal(got, expected, check_exact=True)
    # the band is a band: 2.5 % ≤ median ≤ 97.5 % everywhere
    assert (got.q025 <= got.q50).all() and (got.q50 <= got.q975).all() and (got.p025 < got.p975).all()
    with pytest.raises(ValueError, match="cannot simulate 0.5 A"):
        calibration.simulate(t, x, current=0.5)
    with pytest.raises(ValueError, match="does not increase"):
        calibration.simulate(t[::-1], x)
