"""calibrate: subject-specific human models from motion-capture trials.

What a user needs (see README.md):

    load_model, write_model, Model, Parameters    the base model and the subject's geometry
    read_trial, Trial, Motion                     trials (C3D, TRC) and the solved motion
    calibrate, Calibration                        the calibration and its result
    Settings, Priors, load_settings               the options (and a settings file)
    CalibrateError, ModelError, TrialError        the errors (one line each, naming the file)

Everything else is imported from its sub-package, each documented in its __init__:
calibrate.io (C3D/TRC/CSV/OpenSim files, label maps), calibrate.model (kinematics, the human
model), calibrate.seed (MTB joint centres, marker association), calibrate.problem (the
least-squares problem), calibrate.solve (Levenberg-Marquardt, frame-wise IK),
calibrate.calibration (the pipeline, the report, comparison with a truth), calibrate.simulation
(synthetic trials).
"""

from __future__ import annotations

__version__ = "0.1.0"

from .calibration.pipeline import calibrate
from .calibration.result import Calibration
from .errors import CalibrateError, ModelError, TrialError
from .io.config import load_settings
from .io.motion import Motion
from .io.read import read_trial
from .io.trial import Trial
from .model.model import Model, Parameters, load_model, write_model
from .problem.settings import Priors, Settings

__all__ = [
    "CalibrateError", "Calibration", "Model", "ModelError", "Motion", "Parameters", "Priors", "Settings", "Trial",
    "TrialError", "calibrate", "load_model", "load_settings", "read_trial", "write_model",
]
