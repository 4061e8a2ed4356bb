"""The 3-D view of a calibration in rerun (rerun.io; docs/report.md says why): the subject's skeleton
(joint centres, segments between them, hinge axes), the measured and the model markers over time and
each marker's residual as a line from measured to model, coloured by its length.

`scene_of(cal)` takes a Calibration; `log_report(report, folder)` rebuilds the same from a report JSON
and the files it names (subject URDF, motion CSVs, trials).  `view_scene` opens the viewer or saves a
recording (.rrd, all or nothing).  Positions are logged in metres, time in seconds on the 'time'
timeline and as the frame number on 'frame'.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import CalibrateError
from ..io.outputs import check_targets, write_all
from ..model.blocks import FrameLayout
from ..model.kinematics import build_kinematics
from ..simulation.simulate import joint_axes_world

if TYPE_CHECKING:
    from ..io.motion import Motion
    from ..model.model import Model, Parameters
    from .result import Calibration

AXIS_LENGTH = 0.12  # m, drawn hinge axes


@dataclass(frozen=True)
class Scene:
    """What the 3-D view draws, frame by frame (m)."""

    times: np.ndarray  # (F,) s
    marker_names: tuple[str, ...]
    measured: np.ndarray  # (F, M, 3); NaN where not seen
    model: np.ndarray  # (F, M, 3) the model's markers
    joint_names: tuple[str, ...]
    centres: np.ndarray  # (F, J, 3)
    bones: tuple[tuple[int, int], ...]  # pairs of joint indices joined by a segment
    hinges: tuple[int, ...]  # joint indices of the hinges
    axes: np.ndarray  # (F, H, 3) unit world axis of each hinge


def _bones(model: Model) -> tuple[tuple[int, int], ...]:
    """Segments drawn as lines: from the joint into a segment to every joint out of it."""
    into = {j.child: k for k, j in enumerate(model.joints)}
    return tuple((into[j.parent], k) for k, j in enumerate(model.joints) if j.parent in into)


def _scene(model: Model, params: Parameters, motions: list[Motion], measured: np.ndarray) -> Scene:
    kin = build_kinematics(model)
    Ms, Cs, As, ts = [], [], [], []
    hinges = tuple(k for k, j in enumerate(model.joints) if j.kind == "hinge")
    t_end = 0.0
    for mo in motions:
        M, C = kin.batch(FrameLayout.coordinates(mo.root_translation, mo.angles), mo.root_quaternion, params)
        ax = joint_axes_world(model, params, mo)
        Ms.append(M)
        Cs.append(C)
        As.append(np.stack([ax[model.joints[k].name] for k in hinges], axis=1) if hinges
                  else np.zeros((len(mo.times), 0, 3)))
        ts.append(t_end + mo.times - mo.times[0])  # trials one after another on one timeline
        t_end = ts[-1][-1] + (mo.times[1] - mo.times[0] if len(mo.times) > 1 else 0.01)
    return Scene(np.concatenate(ts), model.marker_names, measured, np.concatenate(Ms),
                 tuple(j.name for j in model.joints), np.concatenate(Cs), _bones(model), hinges,
                 np.concatenate(As))


def scene_of(cal: Calibration) -> Scene:
    """The 3-D scene of a Calibration: measured markers are the model's minus the residuals."""
    sc = _scene(cal.model, cal.params, list(cal.motions), np.empty((0,)))
    return Scene(sc.times, sc.marker_names, sc.model - cal.residuals, sc.model, sc.joint_names, sc.centres,
                 sc.bones, sc.hinges, sc.axes)


def _resolve(name: str, folder: Path) -> Path:
    """A path the report names: as written (from where the calibration ran), else beside the report."""
    p = Path(name)
    for cand in (p, folder / p, folder / p.name):
        if cand.exists():
            return cand
    raise CalibrateError(f"{name}: named by the report but not found (nor in {folder}); run from where the "
                         "calibration ran or put the file beside the report")


def log_report(report: dict, folder: Path) -> Scene:
    """The scene of a report JSON: its subject URDF, motion CSVs and trials (paths as written, else
    relative to `folder`, the report's), trial labels renamed as the calibration renamed them."""
    from ..io.labels import map_labels
    from ..io.motion import read_motion_csv
    from ..io.read import read_trial
    from ..model.model import load_model
    from ..solve.ik import marker_columns

    outs = report.get("outputs") or {}
    if not outs.get("urdf") or not outs.get("motion"):
        raise CalibrateError("the report names no subject URDF or motion CSV (written by the Python API without "
                             "them?); calibrate with -o/--motion, or use calibrate.calibration.view.scene_of")
    model = load_model(_resolve(outs["urdf"], folder))
    motions = [read_motion_csv(_resolve(m, folder)) for m in outs["motion"]]
    measured = []
    for t, mo in zip(report["trials"], motions, strict=False):
        if not t.get("source"):
            raise CalibrateError("a trial of the report was given in memory (no file); the view needs its file")
        trial = read_trial(_resolve(t["source"], folder))
        mapping = {m["label"]: [m["trial_label"]] for m in t.get("labels", []) if m.get("label")}
        trial, _ = map_labels(trial, model.marker_names, mapping, aliases=True)
        start = int(t.get("first_frame", trial.first_frame)) - trial.first_frame
        obs = marker_columns(model, trial)[start:start + mo.n_frames]
        if obs.shape[0] != mo.n_frames:
            raise CalibrateError(f"{t['source']}: has {obs.shape[0]} frames from frame {t.get('first_frame')}, the "
                                 f"motion {mo.n_frames}; is it the trial this report was made from?")
        measured.append(obs)
    sc = _scene(model, model.parameters(), motions, np.empty((0,)))
    return Scene(sc.times, sc.marker_names, np.concatenate(measured), sc.model, sc.joint_names, sc.centres,
                 sc.bones, sc.hinges, sc.axes)


def _colours(err_mm: np.ndarray) -> np.ndarray:
    """Green (0 mm) through yellow to red (10 mm and more), RGB bytes."""
    x = np.clip(np.nan_to_num(err_mm, nan=0.0) / 10.0, 0, 1)[:, None]
    return (255 * np.hstack([np.minimum(1, 2 * x), np.minimum(1, 2 * (1 - x)), np.zeros_like(x)])).astype(np.uint8)


def log_scene(rec, scene: Scene) -> None:
    """Log `scene` frame by frame into the rerun RecordingStream `rec`."""
    import rerun as rr

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    names = list(scene.marker_names)
    for f, t in enumerate(scene.times):
        rec.set_time("frame", sequence=f)
        rec.set_time("time", duration=float(t))
        meas, mod = scene.measured[f], scene.model[f]
        seen = np.isfinite(meas).all(axis=1)
        err = 1000 * np.linalg.norm(mod - meas, axis=1)
        rec.log("markers/measured", rr.Points3D(meas[seen], radii=0.008, colors=[40, 90, 220],
                                                labels=[n for n, s in zip(names, seen, strict=True) if s]))
        rec.log("markers/model", rr.Points3D(mod, radii=0.006, colors=[230, 230, 230]))
        rec.log("markers/residual", rr.LineStrips3D(np.stack([meas[seen], mod[seen]], axis=1),
                                                    colors=_colours(err[seen]), radii=0.003))
        rec.log("residual_mm", rr.AnyValues(marker=[n for n, s in zip(names, seen, strict=True) if s],
                                            error_mm=err[seen]))
        C = scene.centres[f]
        rec.log("skeleton/joints", rr.Points3D(C, radii=0.015, colors=[250, 160, 20], labels=list(scene.joint_names)))
        rec.log("skeleton/segments", rr.LineStrips3D([[C[a], C[b]] for a, b in scene.bones], radii=0.006,
                                                     colors=[200, 200, 200]))
        if scene.hinges:
            origin = C[list(scene.hinges)]
            rec.log("skeleton/hinge_axes", rr.Arrows3D(origins=origin - 0.5 * AXIS_LENGTH * scene.axes[f],
                                                       vectors=AXIS_LENGTH * scene.axes[f], colors=[220, 40, 160]))


def view_scene(scene: Scene, rrd=None, overwrite: bool = False, spawn: bool = True) -> Path | None:
    """Save `scene` as a rerun recording at `rrd` (all or nothing; refuses an existing file unless
    `overwrite`), or without `rrd` open it in a rerun viewer (`spawn`)."""
    try:
        import rerun as rr
    except ImportError:
        raise CalibrateError("the 3-D view needs rerun: pip install rerun-sdk") from None
    if rrd is None:
        rec = rr.RecordingStream("calibrate")
        if spawn:
            rec.spawn()
        log_scene(rec, scene)
        rec.flush()
        return None
    rrd = Path(rrd)
    if rrd.suffix.lower() != ".rrd":
        raise CalibrateError(f"{rrd}: a rerun recording needs an .rrd name")
    check_targets([rrd], overwrite)

    def write(staged: Path) -> None:
        rec = rr.RecordingStream("calibrate")
        rec.save(staged)
        log_scene(rec, scene)
        rec.flush()
        rec.disconnect()

    write_all({rrd: write})
    return rrd
