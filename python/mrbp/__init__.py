"""mrbp from Python: Bayesian calibration of the Bodner-Partom (B-P) model
of MR fluid in MR dampers.

The same Rust library as the ``mrbp`` command line, one import away::

    import mrbp
    campaign = mrbp.Campaign.load("data/campaign.toml")
    cal = mrbp.calibrate(campaign, current=1.0, seed=1)
    cal.summary            # a pandas DataFrame, as summary.parquet
    cal.draws              # every walker's every step, as chains.parquet
    cal.save("results/I1.0A")   # the folder the command line writes
    mrbp.load("results/I1.0A")

Bad input raises ValueError naming the run, row and column; Ctrl-C raises
KeyboardInterrupt. The same seed gives the same chains as ``mrbp sample``,
bit for bit (docs/python.md).
"""

from __future__ import annotations

import warnings
from os import PathLike
from typing import Mapping, Optional, Tuple, Union

import numpy as np
import pandas as pd

from . import _mrbp

__all__ = ["Campaign", "Calibration", "calibrate", "load", "__version__"]
__version__ = _mrbp.version()

Path = Union[str, "PathLike[str]"]


class Campaign:
    """A test campaign: runs of one damper, each a record at a coil current."""

    def __init__(self, inner: _mrbp.Campaign):
        self._inner = inner

    @staticmethod
    def load(manifest: Path) -> "Campaign":
        """Reads a campaign manifest (TOML) and its data files, with the
        checks of ``mrbp check``."""
        return Campaign(_mrbp.Campaign.load(str(manifest)))

    @staticmethod
    def from_frames(
        frames: Mapping[str, "pd.DataFrame"],
        currents: Mapping[str, float],
        geometry: Tuple[float, float],
        name: str = "frames",
        columns: Optional[Mapping[str, str]] = None,
    ) -> "Campaign":
        """A campaign from data frames (pandas, or anything with columns by
        name such as polars), one per run id, in SI units.

        frames: run id -> frame with ``time_s``, ``displacement_m``,
            ``force_n`` and optionally ``current_a`` (other names through
            ``columns``, e.g. ``{"time_s": "t"}``);
        currents: run id -> the run's coil current (A);
        geometry: (working area A in m², gap h in m).

        Checked as a campaign on disk is: a bad value raises ValueError
        naming the run, row and column.
        """
        names = {"time_s": "time_s", "displacement_m": "displacement_m", "force_n": "force_n", "current_a": "current_a"}
        names.update(columns or {})
        runs = []
        for run_id, frame in frames.items():
            if run_id not in currents:
                raise ValueError(f"run '{run_id}': no current given (currents={{'{run_id}': …}})")
            cols = list(frame.columns)

            def column(key: str, required: bool = True):
                name = names[key]
                if name not in cols:
                    if required:
                        raise ValueError(f"run '{run_id}', column '{name}': no such column in the frame")
                    return None
                return np.asarray(frame[name], dtype=np.float64).tolist()

            runs.append(
                (
                    str(run_id),
                    float(currents[run_id]),
                    column("time_s"),
                    column("displacement_m"),
                    column("force_n"),
                    column("current_a", required=False),
                )
            )
        area, gap = geometry
        return Campaign(_mrbp.Campaign.from_arrays(name, float(area), float(gap), runs))

    @property
    def name(self) -> str:
        return self._inner.name

    @property
    def runs(self) -> list:
        """The runs' ids, in order."""
        return self._inner.runs

    @property
    def currents(self) -> list:
        """The coil currents of the runs, each once, rising (A)."""
        return self._inner.currents

    @property
    def notes(self) -> list:
        """What loading noticed but did not refuse."""
        return self._inner.notes

    def __repr__(self) -> str:
        return repr(self._inner)


class Calibration:
    """A calibration: its posterior sample, summary and diagnostics."""

    def __init__(self, inner: _mrbp.Calibration):
        self._inner = inner

    @property
    def summary(self) -> "pd.DataFrame":
        """One row per coordinate, as ``summary.parquet``: mean, sd, q05,
        q50, q95, ess_bulk, ess_tail, r_hat, tau_int, mcse_mean (SI units)."""
        frame = pd.DataFrame(dict(self._inner.summary_columns()))
        frame.insert(0, "parameter", self._inner.summary_parameters())
        return frame

    @property
    def draws(self) -> "pd.DataFrame":
        """Every walker's every step, burn-in included, as
        ``chains.parquet``: ensemble, chain, draw, the coordinates (SI),
        log_prob, accepted. Keep ``draw >= burn_in`` for the posterior."""
        ints, floats, accepted = self._inner.chain_columns()
        columns = {name: np.asarray(v, dtype=np.int64) for name, v in ints}
        columns.update({name: np.asarray(v, dtype=np.float64) for name, v in floats})
        columns["accepted"] = np.asarray(accepted, dtype=bool)
        return pd.DataFrame(columns)

    @property
    def burn_in(self) -> int:
        """The first step of the posterior draws."""
        return self._inner.burn_in

    @property
    def calibration_id(self) -> str:
        return self._inner.calibration_id

    @property
    def max_r_hat(self) -> float:
        return self._inner.max_r_hat

    @property
    def warnings(self) -> list:
        """What the sampler and the model's fit warn about."""
        return self._inner.warnings

    @property
    def folder(self):
        """The folder it was read from or saved to, if any."""
        return self._inner.folder

    def simulate(
        self,
        time,
        displacement,
        current: Optional[float] = None,
        draws: int = 400,
        replicates: int = 10,
        seed: int = 1,
    ) -> "pd.DataFrame":
        """The force of the calibrated damper along an excitation of your own
        (``mrbp simulate``): time (s) and displacement (m) as arrays; the
        coil current (A) as one value, or an array of one value per sample
        (it must hold still for now), or None for a per-current
        calibration's own. Returns a frame with the columns of
        ``simulation.parquet``: the model band of the stress (q025 … q975,
        Pa), the 95 % band of a measured stress (p025, p975) and the same as
        force (force_q025_n … force_p975_n, N). Notes (an extrapolating
        current law, draws that failed) come as warnings."""
        column = None
        if current is not None and np.ndim(current) > 0:
            column, current = np.asarray(current, dtype=np.float64).tolist(), None
        columns, notes = self._inner.simulate(
            np.asarray(time, dtype=np.float64).tolist(),
            np.asarray(displacement, dtype=np.float64).tolist(),
            current=None if current is None else float(current),
            current_column=column,
            draws=int(draws),
            replicates=int(replicates),
            seed=int(seed),
        )
        for note in notes:
            warnings.warn(note, stacklevel=2)
        return pd.DataFrame(dict(columns))

    def save(self, folder: Path, force: bool = False) -> None:
        """Writes the calibration folder ``mrbp sample`` would write (the
        command line's predict, report and compare read it); an earlier
        calibration there is replaced only with ``force=True``."""
        self._inner.save(str(folder), force)

    def __repr__(self) -> str:
        return repr(self._inner)


def calibrate(
    campaign: Campaign,
    current: Optional[float] = None,
    model: Optional[str] = None,
    noise: Optional[str] = None,
    seed: Optional[int] = None,
    steps: Optional[int] = None,
    walkers: Optional[int] = None,
    ensembles: Optional[int] = None,
    substeps: Optional[int] = None,
    config: Optional[Path] = None,
    exact_input: bool = False,
    progress: bool = False,
) -> Calibration:
    """Calibrates the runs of ``campaign`` at ``current`` (or all runs with
    ``model="current-law"``), as ``mrbp sample`` does with the same options:
    the same seed gives the same chains, bit for bit.

    noise: 'gaussian' (default), 'student-t', 'ar1', 'discrepancy';
    steps: a fixed number of steps (default: until R̂ < 1.01 and ESS ≥ 400);
    config: a settings file (TOML) as ``--config``;
    progress: a progress line while sampling.

    The GIL is released while it samples; Ctrl-C raises KeyboardInterrupt.
    """
    inner = _mrbp.calibrate(
        campaign._inner,
        current=current,
        model=model,
        noise=noise,
        seed=seed,
        steps=steps,
        walkers=walkers,
        ensembles=ensembles,
        substeps=substeps,
        config=None if config is None else str(config),
        exact_input=exact_input,
        progress=progress,
    )
    return Calibration(inner)


def load(folder: Path) -> Calibration:
    """Reads a calibration folder written by ``mrbp sample``, ``mrbp run``
    or :meth:`Calibration.save`."""
    return Calibration(_mrbp.Calibration.load(str(folder)))
