"""Type hints of the compiled module behind the `mrbp` package."""

from typing import Any, Callable, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

Floats = npt.NDArray[np.float64]
#: one array of an InferenceData group: name, (dimension, length) pairs,
#: values (a NumPy array, or a list of strings), attributes as JSON
DataNode = Tuple[str, List[Tuple[str, int]], Union[np.ndarray, List[str]], str]

def version() -> str: ...

class Campaign:
    @staticmethod
    def load(manifest: str) -> "Campaign": ...
    @staticmethod
    def from_arrays(
        name: str,
        area_m2: float,
        gap_m: float,
        runs: Sequence[Tuple[str, float, Floats, Floats, Floats, Optional[Floats]]],
    ) -> "Campaign": ...
    @property
    def name(self) -> str: ...
    @property
    def runs(self) -> List[str]: ...
    @property
    def currents(self) -> List[float]: ...
    @property
    def notes(self) -> List[str]: ...

class Calibration:
    @staticmethod
    def load(folder: str) -> "Calibration": ...
    def summary_columns(self) -> List[Tuple[str, Floats]]: ...
    def summary_parameters(self) -> List[str]: ...
    def against_current(self) -> Optional[Tuple[List[str], List[str], List[Tuple[str, Floats]]]]: ...
    def chain_columns(self) -> Tuple[List[Tuple[str, npt.NDArray[np.int64]]], List[Tuple[str, Floats]], npt.NDArray[np.bool_]]: ...
    @property
    def burn_in(self) -> int: ...
    @property
    def calibration_id(self) -> str: ...
    @property
    def log_evidence(self) -> Optional[Tuple[float, float, str, bool]]: ...
    @property
    def max_r_hat(self) -> float: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def folder(self) -> Optional[str]: ...
    def save(self, folder: str, force: bool = False) -> None: ...
    def simulate(
        self,
        time: Floats,
        displacement: Floats,
        current: Optional[float] = None,
        current_column: Optional[Floats] = None,
        draws: int = 400,
        replicates: int = 10,
        seed: int = 1,
        new_test: bool = False,
    ) -> Tuple[List[Tuple[str, Floats]], List[str], List[Tuple[int, int]]]: ...
    def predict(self, draws: int = 400, replicates: int = 10, seed: int = 1) -> Tuple[List[Tuple[str, bytes]], List[Tuple[str, str]], List[str]]: ...
    def inference_data(self, seed: int = 1) -> Tuple[str, List[Tuple[str, str, List[DataNode]]], List[str]]: ...

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
    config: Optional[str] = None,
    exact_input: bool = False,
    progress: Optional[Callable[[str, int, int, Optional[float], Optional[float], Optional[float], float], Any]] = None,
    checkpoint: Optional[str] = None,
    resume: bool = False,
    memory: Optional[str] = None,
    law: Optional[str] = None,
    sampler: Optional[str] = None,
) -> Calibration: ...
