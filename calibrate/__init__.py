"""calibrate: subject-specific human models from motion-capture trials.

The public API (see README.md):

    load_model, write_model, add_markers, Model, Parameters   -- calibrate.model.model
    read_trial, read_c3d, read_trc, write_c3d, write_trc, Trial   -- calibrate.io.trial
    build_kinematics, Kinematics                    -- calibrate.model.kinematics
    inverse_kinematics, IKResult                    -- calibrate.solve.ik
    Motion, read_motion_csv, write_motion_csv       -- calibrate.io.motion
    simulate_squats, simulate_static, write_simulation, Simulation   -- calibrate.simulation.simulate
    simulate_chain, Chain                           -- calibrate.simulation.chains (seed 000's synthetic chains)
    estimate_joints, estimate_model_joints, JointSpec, JointEstimate, JointEstimates,
    write_centres_csv                               -- calibrate.seed.joints (MTB joint centres)
    associate, associate_to_model                   -- calibrate.seed.association (markers -> segments)
    calibrate, Calibration, ParameterChange, NewMarker, Outlier, seed_parameters
                                                    -- calibrate.calibration.pipeline (the global solve)
    Settings, Priors, Problem, load_settings        -- calibrate.problem.problem, calibrate.io.config
    levenberg_marquardt, SolverSummary              -- calibrate.solve.lm
    compare_to_truth, TruthComparison               -- calibrate.calibration.evaluate (against a simulation's truth)
    load_marker_map, map_labels, LabelMapping       -- calibrate.io.labels (trial labels -> model labels)
    CalibrateError, ModelError, TrialError          -- calibrate.errors
"""

from __future__ import annotations

__version__ = "0.1.0"

from .calibration.evaluate import TruthComparison, compare_to_truth
from .calibration.pipeline import ParameterChange, calibrate
from .calibration.result import Calibration, NewMarker, Outlier
from .errors import CalibrateError, ModelError, TrialError
from .io.c3d import read_c3d, write_c3d
from .io.config import load_settings
from .io.labels import LabelMapping, load_marker_map, map_labels
from .io.motion import Motion, read_motion_csv, write_motion_csv
from .io.read import read_trial
from .io.trc import read_trc, write_trc
from .io.trial import Trial
from .model.kinematics import Kinematics, build_kinematics
from .model.model import Model, Parameters, add_markers, load_model, write_model
from .problem.problem import Problem
from .problem.settings import Priors, Settings
from .seed.association import Association, ModelAssociation, associate, associate_to_model
from .seed.joints import (
    JointEstimate,
    JointEstimates,
    JointSpec,
    estimate_joints,
    estimate_model_joints,
    write_centres_csv,
)
from .seed.seeding import seed_parameters
from .simulation.chains import Chain, simulate_chain
from .simulation.simulate import Simulation, simulate_squats, simulate_static, write_simulation
from .solve.ik import IKResult, inverse_kinematics
from .solve.lm import SolverSummary, levenberg_marquardt

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
