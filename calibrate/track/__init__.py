"""Seed 002's 3-D tracker: unlabelled 2-D camera detections -> 3-D marker tracks -> labels of a base model.

``Tracker`` (prediction, the (M+1)-dimensional assignment by Lagrangian relaxation, triangulation),
``solve_assignment`` (the relaxation on its own), ``label_tracks`` (groups, segments, labels) and
``track_subject`` (all of it, then the calibration).  Files: calibrate.io.cameras.  docs/tracking.md.
"""

from .assignment import Assignment, exhaustive_assignment, solve_assignment
from .labels import Labelling, label_tracks
from .subject import TrackedSubject, track_subject
from .tracker import Tracker, Tracks, TrackSettings

__all__ = ["Assignment", "Labelling", "TrackSettings", "TrackedSubject", "Tracker", "Tracks", "exhaustive_assignment",
           "label_tracks", "solve_assignment", "track_subject"]
