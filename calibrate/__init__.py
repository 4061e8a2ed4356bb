"""calibrate: subject-specific human models from motion-capture trials.

The public API (see README.md):

    load_model, write_model, add_markers, Model, Parameters   -- calibrate.model
    read_trial, read_c3d, read_trc, write_c3d, write_trc, Trial   -- calibrate.trial
    build_kinematics, Kinematics                    -- calibrate.kinematics
    inverse_kinematics, IKResult                    -- calibrate.ik
    Motion, read_motion_csv, write_motion_csv       -- calibrate.motion
    simulate_squats, simulate_static, write_simulation, Simulation   -- calibrate.simulate
    simulate_chain, Chain                           -- calibrate.chains (seed 000's synthetic chains)
    estimate_joints, estimate_model_joints, JointSpec, JointEstimate, JointEstimates,
    write_centres_csv                               -- calibrate.joints (MTB joint centres)
    associate, associate_to_model                   -- calibrate.association (markers -> segments)
    calibrate, Calibration, ParameterChange, NewMarker, Outlier, seed_parameters
                                                    -- calibrate.calibration (the global solve)
    Settings, Priors, Problem, load_settings        -- calibrate.problem, calibrate.config
    levenberg_marquardt, SolverSummary              -- calibrate.solver
    compare_to_truth, TruthComparison               -- calibrate.evaluate (against a simulation's truth)
    load_marker_map, map_labels, LabelMapping       -- calibrate.labels (trial labels -> model labels)
    CalibrateError, ModelError, TrialError          -- calibrate.errors
"""

from __future__ import annotations

__version__ = "0.1.0"

from .association import Association, ModelAssociation, associate, associate_to_model
from .calibration import Calibration, NewMarker, Outlier, ParameterChange, calibrate, seed_parameters
from .chains import Chain, simulate_chain
from .config import load_settings
from .errors import CalibrateError, ModelError, TrialError
from .evaluate import TruthComparison, compare_to_truth
from .ik import IKResult, inverse_kinematics
from .joints import (
    JointEstimate,
    JointEstimates,
    JointSpec,
    estimate_joints,
    estimate_model_joints,
    write_centres_csv,
)
from .kinematics import Kinematics, build_kinematics
from .labels import LabelMapping, load_marker_map, map_labels
from .model import Model, Parameters, add_markers, load_model, write_model
from .motion import Motion, read_motion_csv, write_motion_csv
from .problem import Priors, Problem, Settings
from .simulate import Simulation, simulate_squats, simulate_static, write_simulation
from .solver import SolverSummary, levenberg_marquardt
from .trial import Trial, read_c3d, read_trc, read_trial, write_c3d, write_trc

__all__ = [
    "Calibration", "NewMarker", "Outlier", "ParameterChange", "Priors", "Problem", "Settings", "SolverSummary",
    "TruthComparison", "calibrate", "compare_to_truth", "levenberg_marquardt", "load_settings", "seed_parameters",
    "Association", "CalibrateError", "Chain", "IKResult", "JointEstimate", "JointEstimates", "JointSpec",
    "Kinematics", "Model", "ModelAssociation", "ModelError", "Motion", "Parameters", "Simulation", "Trial",
    "TrialError", "add_markers", "associate", "associate_to_model", "build_kinematics", "estimate_joints",
    "estimate_model_joints", "inverse_kinematics", "load_model", "read_c3d", "read_motion_csv", "read_trc",
    "read_trial", "simulate_chain", "simulate_squats", "simulate_static", "write_c3d", "write_centres_csv",
    "write_model", "write_motion_csv", "write_simulation", "write_trc", "LabelMapping", "load_marker_map",
    "map_labels",
]
