"""calibrate: subject-specific human models from motion-capture trials.

The public API (see README.md):

    load_model, write_model, Model, Parameters      -- calibrate.model
    read_trial, read_c3d, read_trc, write_c3d, write_trc, Trial   -- calibrate.trial
    build_kinematics, Kinematics                    -- calibrate.kinematics
    inverse_kinematics, IKResult                    -- calibrate.ik
    Motion, read_motion_csv, write_motion_csv       -- calibrate.motion
    simulate_squats, write_simulation, Simulation   -- calibrate.simulate
    CalibrateError, ModelError, TrialError          -- calibrate.errors
"""

from __future__ import annotations

from .errors import CalibrateError, ModelError, TrialError
from .ik import IKResult, inverse_kinematics
from .kinematics import Kinematics, build_kinematics
from .model import Model, Parameters, load_model, write_model
from .motion import Motion, read_motion_csv, write_motion_csv
from .simulate import Simulation, simulate_squats, write_simulation
from .trial import Trial, read_c3d, read_trc, read_trial, write_c3d, write_trc

__version__ = "0.1.0"

__all__ = [
    "CalibrateError", "IKResult", "Kinematics", "Model", "ModelError", "Motion", "Parameters", "Simulation",
    "Trial", "TrialError", "build_kinematics", "inverse_kinematics", "load_model", "read_c3d",
    "read_motion_csv", "read_trc", "read_trial", "simulate_squats", "write_c3d", "write_model",
    "write_motion_csv", "write_simulation", "write_trc",
]
