"""mrbp from Python: Bayesian calibration of the Bodner-Partom (B-P) model
of MR fluid in MR dampers.

The same Rust library as the ``mrbp`` command line, one import away::

    import mrbp
    campaign = mrbp.Campaign.load("data/campaign.toml")
    cal = mrbp.calibrate(campaign, current=1.0, seed=1)
    cal.summary            # a pandas DataFrame, as summary.parquet
    cal.draws              # every walker's every step, as chains.parquet
    cal.predict().bands    # the model and predictive bands of the runs
    cal.to_inference_data()     # ArviZ: az.summary, az.plot_trace, az.loo
    cal.simulate(t, x)     # the force along an excitation of your own
    cal.save("results/I1.0A")   # the folder the command line writes
    mrbp.load("results/I1.0A")

Bad input raises ValueError naming the run, row and column; Ctrl-C raises
KeyboardInterrupt. The same seed gives the same chains as ``mrbp sample``,
bit for bit (docs/python.md).
"""

from __future__ import annotations

import io
import json
import sys
import time as _time
import warnings
from dataclasses import dataclass, field
from os import PathLike
from typing import Callable, Dict, Mapping, Optional, Tuple, Union

import numpy as np
import pandas as pd

from . import _mrbp

__all__ = ["Campaign", "Calibration", "Prediction", "calibrate", "load", "__version__"]
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
                try:
                    # read in place by the library when already contiguous float64
                    return np.ascontiguousarray(frame[name], dtype=np.float64)
                except (TypeError, ValueError) as e:
                    raise ValueError(f"run '{run_id}', column '{name}': not numbers ({e})") from None

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


@dataclass
class Prediction:
    """The bands of a calibration's runs (``Calibration.predict``): the
    tables ``mrbp predict`` writes, as frames."""

    bands: "pd.DataFrame"
    coverage: "pd.DataFrame"
    adequacy: "pd.DataFrame"
    #: runs that could not be predicted: run id -> why
    failed: Dict[str, str] = field(default_factory=dict)


class _Progress:
    """A progress display for ``calibrate(progress=True)``: a tqdm bar
    (a widget in a notebook) when tqdm is installed, else one line on
    ``sys.stderr`` rewritten in place (a notebook shows it in the cell)."""

    def __init__(self):
        try:
            from tqdm.auto import tqdm
        except ImportError:
            tqdm = None
        self._tqdm = tqdm
        self._bar = None
        self._shown = 0.0

    def __call__(self, stage, step, max_steps, ess, ess_target, r_hat, acceptance):
        status = f"acceptance {acceptance:.2f}"
        if ess is not None:
            target = f"/{ess_target:.0f}" if ess_target is not None else ""
            status += f", smallest ESS {ess:.0f}{target}, largest R̂ {r_hat:.4f}"
        if self._tqdm is not None:
            if self._bar is None:
                self._bar = self._tqdm(total=max_steps, desc="sampling", unit="step", initial=step)
            self._bar.n = step
            self._bar.set_postfix_str(status, refresh=False)
            self._bar.refresh()
            if stage == "finished":
                self._bar.close()
            return
        now = _time.monotonic()
        if stage == "step" and now - self._shown < 0.5:
            return
        self._shown = now
        end = "\n" if stage == "finished" else ""
        print(f"\rsampling: step {step} of at most {max_steps}, {status}   ", end=end, file=sys.stderr, flush=True)


class Calibration:
    """A calibration: its posterior sample, summary and diagnostics."""

    def __init__(self, inner: _mrbp.Calibration):
        self._inner = inner

    @property
    def summary(self) -> "pd.DataFrame":
        """One row per coordinate, as ``summary.parquet``: mean, sd, q05,
        q50, q95, ess_bulk, ess_tail, r_hat, tau_int, mcse_mean (SI units).
        What the intervals hold for, and where the likelihood allowed for
        the residuals' memory the intervals had they been taken as
        independent, are in summary.parquet's ``holds_for`` and
        ``independent_*`` columns."""
        frame = pd.DataFrame(dict(self._inner.summary_columns()))
        frame.insert(0, "parameter", self._inner.summary_parameters())
        return frame

    @property
    def against_current(self) -> Optional["pd.DataFrame"]:
        """A law's (``model="current-law"`` or ``"current-curves"``) B-P
        parameters against the coil current, as ``against_current.parquet``:
        parameter, current_a, kind ('calibrated', 'between', 'outside'),
        mean, sd, q05, q50, q95 (SI); None for a calibration at one current."""
        made = self._inner.against_current()
        if made is None:
            return None
        parameters, kinds, columns = made
        frame = pd.DataFrame(dict(columns))
        frame.insert(0, "parameter", parameters)
        frame.insert(2, "kind", kinds)
        return frame

    @property
    def draws(self) -> "pd.DataFrame":
        """Every walker's every step, burn-in included, as
        ``chains.parquet``: ensemble, chain, draw, the coordinates (SI),
        log_prob, accepted. Keep ``draw >= burn_in`` for the posterior."""
        ints, floats, accepted = self._inner.chain_columns()
        columns = dict(ints)
        columns.update(floats)
        columns["accepted"] = accepted
        return pd.DataFrame(columns)

    @property
    def burn_in(self) -> int:
        """The first step of the posterior draws."""
        return self._inner.burn_in

    @property
    def calibration_id(self) -> str:
        return self._inner.calibration_id

    @property
    def log_evidence(self) -> Optional[dict]:
        """Where the calibration was sampled by sequential Monte Carlo
        (``sampler="smc"``): ``{"log_evidence", "se", "of", "pseudo"}``, the
        log evidence ln p(records | law, priors, noise model), its standard
        error, what it is of, and whether it is a pseudo-evidence (of a
        likelihood tempered or adjusted for the residuals' memory:
        comparable only between calibrations that allowed for it alike).
        None for the ensemble sampler alone."""
        found = self._inner.log_evidence
        if found is None:
            return None
        value, se, of, pseudo = found
        return {"log_evidence": value, "se": se, "of": of, "pseudo": pseudo}

    def evidence(self) -> dict:
        """The log evidence of any calibration: ``{"log_evidence", "se",
        "of", "pseudo", "by"}`` — sequential Monte Carlo's where it was
        sampled so (``by`` = "sequential Monte Carlo", as
        :attr:`log_evidence`), else computed by bridge sampling from the
        ensemble sampler's chains (``by`` = "bridge sampling": some 4 000
        log-densities, seconds), as ``mrbp evidence DIR`` prints it."""
        value, se, of, pseudo, by = self._inner.evidence()
        return {"log_evidence": value, "se": se, "of": of, "pseudo": pseudo, "by": by}

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
        new_test: bool = False,
    ) -> "pd.DataFrame":
        """The force of the calibrated damper along an excitation of your own
        (``mrbp simulate``): time (s) and displacement (m) as arrays; the
        coil current (A) as one value, or an array of one value per sample
        (a law follows it where it changes, the field trailing it by the
        law's coil lag), or None for a per-current calibration's own. Returns a frame with the columns of
        ``simulation.parquet``: the model band of the stress (q025 … q975,
        Pa), the 95 % band of a measured stress (p025, p975) and the same as
        force (force_q025_n … force_p975_n, N). Notes (an extrapolating
        current law, draws that failed) come as warnings.

        ``new_test=True`` is ``simulate --new-test``: new tests of the
        damper from the between-run layer of a calibration read from a
        folder made with ``--per-run``, in place of its posterior — the
        band a test not yet run would fall in; with ``current`` between
        the calibrated currents (runs alone at two currents or more) the
        layer is fitted again predicting that current."""
        column = None
        if current is not None and np.ndim(current) > 0:
            column, current = np.ascontiguousarray(current, dtype=np.float64), None
        columns, notes, positions = self._inner.simulate(
            np.ascontiguousarray(time, dtype=np.float64),
            np.ascontiguousarray(displacement, dtype=np.float64),
            current=None if current is None else float(current),
            current_column=column,
            draws=int(draws),
            replicates=int(replicates),
            seed=int(seed),
            new_test=bool(new_test),
        )
        for note in notes:
            warnings.warn(note, stacklevel=2)
        frame = pd.DataFrame(dict(columns), copy=False)
        # the posterior draws propagated: (draw, chain) rows of .draws (none
        # for new tests)
        frame.attrs["draws"] = [(int(s), int(c)) for s, c in positions]
        return frame

    def predict(self, draws: int = 400, replicates: int = 10, seed: int = 1) -> "Prediction":
        """The bands of the calibration's runs, as ``mrbp predict`` writes
        them (the same numbers at the same options): ``.bands`` (one row per
        run and sample: the model band q025 … q975 and the 95 % predictive
        band p025, p975 of the shear stress, Pa, beside the record),
        ``.coverage`` (one row per run: the share of samples inside each
        band, lppd) and ``.adequacy`` (one row per run: where the law misses
        the record). Runs that cannot be predicted are left out, named in
        ``.failed`` and in a warning.

        A current law predicts every run of its campaign; a per-current
        calibration its own runs."""
        tables, failed, notes = self._inner.predict(int(draws), int(replicates), int(seed))
        frames = {name: pd.read_parquet(io.BytesIO(data)) for name, data in tables}
        for note in notes:
            warnings.warn(note, stacklevel=2)
        for run, why in failed:
            warnings.warn(f"{run}: not predicted: {why}", stacklevel=2)
        return Prediction(
            bands=frames["bands.parquet"],
            coverage=frames["coverage.parquet"],
            adequacy=frames["adequacy.parquet"],
            failed=dict(failed),
        )

    def to_inference_data(self, seed: int = 1):
        """The calibration as ArviZ's ``InferenceData``, built in memory:
        the groups of ``inference.zarr`` (posterior, sample_stats,
        log_likelihood, posterior_predictive, observed_data) with the same
        values, so ``az.summary``, ``az.plot_trace`` and ``az.loo(idata,
        reff=1.0)`` work on it. ``seed`` seeds the replicated records, as
        ``mrbp predict --predict-seed``. Needs ``arviz`` and ``xarray``.

        One chain is one walker; the root's and each group's attributes say
        how mrbp's R̂ (over independent ensembles, in ``.summary``) differs
        from ArviZ's over walkers."""
        import arviz as az
        import xarray as xr

        root, groups, notes = self._inner.inference_data(int(seed))
        for note in notes:
            warnings.warn(note, stacklevel=2)
        datasets = {}
        for name, attrs, nodes in groups:
            named = set()
            for _, _, _, node_attrs in nodes:
                named.update(json.loads(node_attrs).get("coordinates", "").split())
            coords, variables = {}, {}
            for node, dims, values, node_attrs in nodes:
                node_attrs = json.loads(node_attrs)
                node_attrs.pop("coordinates", None)
                shape = tuple(n for _, n in dims)
                dim_names = tuple(d for d, _ in dims)
                values = np.asarray(values).reshape(shape)
                entry = (dim_names, values, node_attrs)
                if (len(dims) == 1 and dims[0][0] == node) or node in named:
                    coords[node] = entry
                else:
                    variables[node] = entry
            datasets[name] = xr.Dataset(variables, coords=coords, attrs=json.loads(attrs))
        return az.InferenceData(attrs=json.loads(root), **datasets)

    def save(self, folder: Path, force: bool = False) -> None:
        """Writes the calibration folder ``mrbp sample`` would write (the
        command line's predict, report and compare read it); an earlier
        calibration there is replaced only with ``force=True``. A campaign
        made from frames is written beside it first (``records/``: a
        manifest and one CSV per run), so the command line finds its
        records."""
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
    progress: Union[bool, Callable[..., None]] = False,
    checkpoint: Optional[Path] = None,
    resume: bool = False,
    memory: Optional[str] = None,
    law: Optional[str] = None,
    sampler: Optional[str] = None,
) -> Calibration:
    """Calibrates the runs of ``campaign`` at ``current`` (or all runs with
    ``model="current-law"``), as ``mrbp sample`` does with the same options:
    the same seed gives the same chains, bit for bit.

    law: the damper law, as ``--law``: 'bodner-partom' (default),
        'bp-viscous', 'bouc-wen', 'spencer', 'bingham', 'bp-spencer' (docs/calibration.md,
        "Damper laws");
    noise: 'gaussian' (default), 'student-t', 'ar1', 'discrepancy';
    sampler: 'ensemble' (default) or 'smc', as ``--sampler``: tempered
        sequential Monte Carlo first, which gives the log evidence
        (:attr:`Calibration.log_evidence`);
    memory: 'auto' (default: independent where the MAP residuals have no
        memory, else 'adjusted'), 'independent', 'tempered' (each run's
        log-likelihood divided by its residuals' integrated autocorrelation
        time, as ``--memory tempered``) or 'adjusted' (each parameter
        widened by the memory of the part of the records that informs it);
    steps: a fixed number of steps (default: until R̂ < 1.01 and ESS ≥ 400);
    config: a settings file (TOML) as ``--config``;
    progress: True for a progress bar (tqdm's where installed, a notebook
        widget in Jupyter; else a line on stderr), or a callable
        ``f(stage, step, max_steps, ess, ess_target, r_hat, acceptance)``
        called at "started", every "step" and "finished" (ess and r_hat are
        None until the first convergence check);
    checkpoint: a file for the sampler's state, saved every 100 steps and
        at Ctrl-C (and removed when the calibration is done); with
        ``sampler="smc"`` the finished populations go beside it, in
        ``smc.checkpoint`` of the same folder;
    resume: continue from ``checkpoint`` (with the same options): the
        chains equal an uninterrupted run's, bit for bit.

    The GIL is released while it samples; Ctrl-C raises KeyboardInterrupt
    at the next step (with the checkpoint saved, if one is kept).
    """
    if progress is True:
        progress = _Progress()
    elif progress is False or progress is None:
        progress = None
    elif not callable(progress):
        raise ValueError("progress: True, False or a callable")
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
        checkpoint=None if checkpoint is None else str(checkpoint),
        resume=resume,
        memory=memory,
        law=law,
        sampler=sampler,
    )
    return Calibration(inner)


def load(folder: Path) -> Calibration:
    """Reads a calibration folder written by ``mrbp sample``, ``mrbp run``
    or :meth:`Calibration.save`."""
    return Calibration(_mrbp.Calibration.load(str(folder)))
