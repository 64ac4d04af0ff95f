"""Type hints of the compiled module behind the `mrbp` package."""

from typing import List, Optional, Sequence, Tuple

def version() -> str: ...

class Campaign:
    @staticmethod
    def load(manifest: str) -> "Campaign": ...
    @staticmethod
    def from_arrays(
        name: str,
        area_m2: float,
        gap_m: float,
        runs: Sequence[Tuple[str, float, Sequence[float], Sequence[float], Sequence[float], Optional[Sequence[float]]]],
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
    def summary_columns(self) -> List[Tuple[str, List[float]]]: ...
    def summary_parameters(self) -> List[str]: ...
    def chain_columns(self) -> Tuple[List[Tuple[str, List[int]]], List[Tuple[str, List[float]]], List[bool]]: ...
    @property
    def burn_in(self) -> int: ...
    @property
    def calibration_id(self) -> str: ...
    @property
    def max_r_hat(self) -> float: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def folder(self) -> Optional[str]: ...
    def save(self, folder: str, force: bool = False) -> None: ...
    def simulate(
        self,
        time: Sequence[float],
        displacement: Sequence[float],
        current: Optional[float] = None,
        current_column: Optional[Sequence[float]] = None,
        draws: int = 400,
        replicates: int = 10,
        seed: int = 1,
    ) -> Tuple[List[Tuple[str, List[float]]], List[str]]: ...

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
    progress: bool = False,
) -> Calibration: ...
