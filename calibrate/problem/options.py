"""Options of the Levenberg–Marquardt solver (calibrate.solve.lm), passed to it by the caller."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class SolverOptions:
    """When Levenberg–Marquardt stops, and how it steps (the meanings of Settings' fields of the same names)."""

    max_iterations: int = 100
    ftol: float = 1e-6  # stop when the relative cost decrease of a step falls below this (as Ceres)
    atol: float = 0.5  # ... or a step lowers the cost by less than this: χ² by less than 1, its one-sigma level
    xtol: float = 1e-8  # ... or the step is smaller than xtol * (|x| + xtol)
    gtol: float = 1e-10  # ... or the largest gradient entry is below this
    geodesic: bool = True  # geodesic acceleration of the steps (follows curved valleys; least squares only)

    def __post_init__(self) -> None:
        for name in ("ftol", "atol", "xtol", "gtol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {self.max_iterations!r}")
