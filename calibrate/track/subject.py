"""Seed 002 end to end: unlabelled 2-D detections -> tracks -> groups -> labels of a base model -> the global
calibration of that model to the subject."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..io.cameras import Camera, Detections
from ..io.trial import Trial
from ..model.model import Model
from .labels import Labelling, label_tracks
from .tracker import Tracker, Tracks, TrackSettings


@dataclass(frozen=True)
class TrackedSubject:
    """Everything `track_subject` made."""

    tracks: Tracks
    labelling: Labelling
    trial: Trial  # the labelled trajectories (unlabelled tracks keep their names T<i>)
    calibration: object  # calibrate.calibration.result.Calibration

    def report(self) -> dict:
        """The calibration's report with the tracker's figures and the labels."""
        rep = self.calibration.report()
        rep["tracker"] = self.tracks.figures()
        rep["tracker"]["written_tracks"] = self.trial.n_markers
        rep["tracker"]["new_tracks_after_first_frame"] = int(sum(1 for s in self.tracks.started if s > 0))
        # breaks: a marker's track lost and found again as another (joined by stitching or by the labelling)
        _, chains = self.tracks.stitched()
        rep["tracker"]["breaks_joined"] = int(sum(len(c) - 1 for c in chains)) + len(self.labelling.merged)
        rep["labels"] = {"tracks": self.labelling.labels, "groups": self.labelling.groups,
                         "scale": self.labelling.scale, "merged": self.labelling.merged,
                         "unlabelled": [x for x in self.trial.labels if x not in self.labelling.labels.values()]}
        return rep


def track_subject(cameras: Sequence[Camera], detections: Detections, model: Model,
                  settings: TrackSettings | None = None, min_frames: int = 10, calibration_settings=None,
                  progress: Callable | None = None) -> TrackedSubject:
    """Track the markers (calibrate.track.tracker), label the tracks with `model`'s markers
    (calibrate.track.labels) and calibrate `model` to them (calibrate.calibrate).  `progress`: each stage's
    messages (calibrate.calibration.records.Progress: 'track' with the frames done, 'labels' step by step, then
    the calibration's), as the calibrate command prints them."""
    from ..calibration.pipeline import calibrate
    from ..calibration.records import Countdown

    count = None
    if progress is not None:
        count = Countdown(progress, "track", f"tracking {detections.n_frames} frames of {len(cameras)} cameras")
    tracks = Tracker(cameras, settings).run(detections, None if count is None else lambda k, n: count(k / n))
    unlabelled = tracks.trial(min_frames)
    labelling = label_tracks(model, unlabelled, progress)
    trial = labelling.trial(unlabelled)
    cal = calibrate(model, trial, calibration_settings, aliases=False, progress=progress)
    return TrackedSubject(tracks, labelling, trial, cal)
