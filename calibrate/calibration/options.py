"""The pipeline's options (calibrate.calibration.pipeline): its switches and thresholds, a typed view of the
user's flat Settings (Settings.pipeline)."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Settings.hip_regression's modes besides true and false: "auto" (where a hip ends implausible) and "outside" (where
#: the hips end outside the pelvis or on its midline, the default); calibrate.calibration.pipeline._hips_auto.
HIP_MODES = ("auto", "outside")


@dataclass(frozen=True)
class PipelineOptions:
    """What calibrate() does around the solves (the meanings of Settings' fields of the same names)."""

    seed: bool = True  # start from MTB joint centres (else from the base model)
    new_markers: bool = True  # place trial markers the model does not know on segments and fit them
    outliers: float = 6.0  # reject a marker in a frame whose error exceeds this many noise SDs (0: keep all)
    auto_hold: bool = True  # hold the axes of the coordinates the trial does not show moving (Settings.auto_hold)
    segment_frames: str | None = None  # "markers" | "priors" | None: the model's (Settings.segment_frames)
    learn_noise: bool = True  # learn each marker's noise SD from the residuals (Settings.learns_noise: decided)
    ahead: bool = True  # the start's GIL-bound parts in a forked process on the other core (same results)
    still_weight: float = 0.0  # frames a still trial counts as in all beside a moving one (0: every frame once)
    moved_markers: bool = False  # a still trial's positions of markers the moving trials put elsewhere: left out
    # hip centres by Harrington's regression ("auto": where they end implausible; "outside": outside the pelvis or on
    # its midline)
    hip_regression: bool | str = "outside"
    far_joints: bool = True  # a still trial's markers beyond a joint it holds where no moving trial goes: left out

    def __post_init__(self) -> None:
        if self.segment_frames not in (None, "markers", "priors"):
            raise ValueError(f"segment_frames: must be 'markers' or 'priors', got {self.segment_frames!r}")
        if not isinstance(self.ahead, bool):
            raise ValueError(f"ahead: must be true or false, got {self.ahead!r}")
        if not (isinstance(self.still_weight, (int, float)) and self.still_weight >= 0
                and math.isfinite(self.still_weight)):
            raise ValueError(f"still_weight: must be 0 (off) or a positive number of frames, got {self.still_weight!r}")
        if not isinstance(self.moved_markers, bool):
            raise ValueError(f"moved_markers: must be true or false, got {self.moved_markers!r}")
        if not isinstance(self.far_joints, bool):
            raise ValueError(f"far_joints: must be true or false, got {self.far_joints!r}")
        if not (isinstance(self.hip_regression, bool) or self.hip_regression in HIP_MODES):
            raise ValueError(f"hip_regression: must be true, false, \"auto\" or \"outside\", got "
                             f"{self.hip_regression!r}")
        if not isinstance(self.learn_noise, bool):
            raise ValueError(f"learn_noise: must be true or false, got {self.learn_noise!r}")
        if not (isinstance(self.outliers, (int, float)) and self.outliers >= 0 and math.isfinite(self.outliers)):
            raise ValueError(f"outliers: must be 0 (off) or a positive number of noise SDs, got {self.outliers!r}")
