"""The global calibration problem of seed 003: every frame's coordinates z_f and the
geometric parameters p shared by all frames, as one nonlinear least-squares problem.

Cost (dimensionless):

    ½ Σ_f Σ_k∈seen(f) ρ(|h_k(z_f, p) − r_fk|² / σ²)   +   ½ |prior(p)|²

* σ is the marker noise (``Settings.noise``, or per marker ``Settings.marker_noise``);
  ρ is the identity, Huber or Cauchy (``Settings.loss``, scale ``loss_scale`` σ).  Markers
  not seen in a frame (gaps) have no row at all in that frame.
* prior(p) pulls the parameters towards the base model, each group with its own standard
  deviation (``Priors``): a marker offset by  s_seg (m − m₀)/σ_marker, a joint centre by
  s_parent (c − c₀)/σ_centre (both in metres *at the current scale*), a hinge axis by
  (a − a₀)/σ_axis (≈ the angle between them, rad) and a scale factor by (s − 1)/σ_scale.
  The priors hold what a trial cannot identify (a hinge centre's position along its axis,
  a joint that never moves, how a segment's size splits between its scale factor and its
  offsets) and barely move what it can.

Free parameters (``Settings.free``) are a subset of the groups scale / centre / axis /
marker.  Hinge and universal-joint axes are kept unit by a two-parameter tangent update
(a ← normalise(a + B u), B ⟂ a); the three axes of a ball joint are never calibrated.

Evaluation: one CasADi function per frame gives the raw marker residuals and the exact
nonzeros of ∂/∂z and ∂/∂p; it is mapped over all frames (``Function.map``, two threads)
and, when a C compiler is available, generated as C and compiled once per model (cached
in ``$CALIBRATE_CACHE`` or ~/.cache/calibrate), otherwise run in CasADi's virtual machine.
The Jacobian nonzeros are gathered per segment into small dense blocks, from which the
block-arrow normal equations (per-frame blocks A_f, couplings B_f, parameter block C)
are built without ever forming the full matrix.
"""

from __future__ import annotations

import copy
import hashlib
import math
import os
import subprocess
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.blocks import GROUPS, ParameterLayout, cross3, perpendicular_basis  # noqa: F401
from ..model.kinematics import Kinematics, build_kinematics
from ..model.model import Model, Parameters
from ..solve.assembly import assemble, c_compiler, cache_dir, group_layout, in_parallel, parameter_layout, split_frames  # noqa: F401
from .options import SolverOptions

LIMIT_WEIGHT = 1.0  # m of marker error per rad beyond a joint limit (as in calibrate.solve.ik)
LOCK_WEIGHT = 100.0  # m of marker error per rad away from a locked coordinate's value (Settings.lock)
LIMIT_MARGIN = math.radians(15.0)  # the limits of the global problem are this much wider than the model's
LOSSES = ("linear", "huber", "cauchy")
EVAL_BLOCK = 128  # frames per mapped CasADi call (building a map costs more than linearly in its size)
FrameTurn = tuple[int, str, np.ndarray, np.ndarray]  # (segment, gauge kind, rotation G, shift t) of a frame turn
NOISE_DEFAULT = 0.001  # m: Settings.noise unless given (then learnt from the data: Settings.learn_noise)
EVAL_PAD = 32  # a shorter last block is padded to EVAL_BLOCK frames when longer than this (one map size)


@dataclass(frozen=True)
class Priors:
    """Standard deviations of the priors that pull p towards the base model."""

    marker: float = 0.02  # m: how far a subject's marker may sit from the base model's place
    centre: float = 0.02  # m: same for a joint centre
    axis: float = math.radians(10.0)  # rad: tilt of a hinge axis
    scale: float = 0.25  # fraction: segment scale factor about 1
    # Left/right symmetry (segments and joints named *_l / *_r; 0: off): SD of the difference between
    # a left segment's scale factor and its right partner's (fraction), and between a left joint centre
    # and its right partner's mirrored through the sagittal plane (m, at the subject's scale), each
    # counted relative to the base model's own asymmetry.  Soft-tissue artefact pulls the two sides
    # apart by different amounts; a subject's bones are symmetric to a few per cent.
    symmetry_scale: float = 0.05
    symmetry_centre: float = 0.02


@dataclass(frozen=True)
class Settings:
    """What is calibrated and how.  Units: metres, radians."""

    free: tuple[str, ...] = GROUPS  # parameter groups the solve may change
    noise: float = NOISE_DEFAULT  # m: marker noise SD (weights the marker residuals; the start when learnt)
    loss: str = "linear"  # 'linear', 'huber' or 'cauchy'
    loss_scale: float = 3.0  # in units of `noise`: residuals beyond it count less (robust losses)
    priors: Priors = field(default_factory=Priors)
    # The solver's options (calibrate.problem.options.SolverOptions; `solver` gives them to levenberg_marquardt):
    max_iterations: int = 100
    ftol: float = 1e-6  # stop when the relative cost decrease of a step falls below this (as Ceres)
    atol: float = 0.5  # ... or a step lowers the cost by less than this: χ² by less than 1, its one-sigma level
    xtol: float = 1e-8  # ... or the step is smaller than xtol * (|x| + xtol)
    gtol: float = 1e-10  # ... or the largest gradient entry is below this
    seed: bool = True  # start from MTB joint centres (else from the base model)
    compile: bool = True  # compile the per-frame function with the C compiler, if there is one
    new_markers: bool = True  # place trial markers the model does not know on segments (by rigidity) and fit them
    outliers: float = 6.0  # reject a marker in a frame whose error exceeds this many noise SDs (0: keep all)
    geodesic: bool = True  # geodesic acceleration of the LM steps (follows curved valleys; calibrate.solve.lm)
    # Per-marker noise SD (m) where a marker is noisier or steadier than `noise`, e.g. wand markers
    # on soft tissue: ((label, SD), ...) or a dict.  An OpenSim marker weight w is the SD noise/sqrt(w).
    marker_noise: tuple[tuple[str, float], ...] = ()
    # Coordinates held at a value (rad) in every frame, as OpenSim's locked coordinates: DoFs the
    # marker set cannot resolve (e.g. the subtalar joint under a two-marker foot).  ((DoF, angle), ...),
    # a dict, or DoF names (held at 0).  A locked hinge's axis is not calibrated.
    lock: tuple[tuple[str, float], ...] = ()
    # Hinge and universal DoFs whose axis keeps the base model's direction (their angles stay free).
    hold_axes: tuple[str, ...] = ()
    # Hold, as above, the axis of every coordinate the trial does not show moving (calibrate decides
    # after the solve on the subsample, and says so): a joint that hardly moves cannot place its
    # axis, and left free the axis drifts far from the base model's by fitting noise.
    auto_hold: bool = True
    # Segments whose geometry is held at the base model's: their scale, the joint centres and markers
    # expressed in them, the axes of the joints into them.  calibrate holds the segments with no seen
    # marker on or below them (calibrate.model.resolve): nothing in the data reaches their parameters, and
    # left free only the priors' couplings (e.g. left/right symmetry) would move them.
    hold_segments: tuple[str, ...] = ()
    # Learn each marker's noise SD from the trial's residuals (a robust scale, iterated with the solve;
    # calibrate.calibration.pipeline.learned_noise) instead of taking `noise` for all.  None (default): learn
    # unless `noise` was set away from NOISE_DEFAULT; markers named in `marker_noise` keep their value.
    learn_noise: bool | None = None

    @property
    def solver(self) -> SolverOptions:
        """The options of the Levenberg–Marquardt solver among these settings (calibrate.solve.lm)."""
        return SolverOptions(self.max_iterations, self.ftol, self.atol, self.xtol, self.gtol, self.geodesic)

    @property
    def learns_noise(self) -> bool:
        """Whether calibrate learns the markers' noise SDs from the data (see `learn_noise`)."""
        return self.noise == NOISE_DEFAULT if self.learn_noise is None else bool(self.learn_noise)

    def __post_init__(self) -> None:
        hold = (self.hold_axes,) if isinstance(self.hold_axes, str) else self.hold_axes
        object.__setattr__(self, "hold_axes", tuple(sorted(set(hold))))
        for name in self.hold_axes:
            if not isinstance(name, str):
                raise ValueError(f"hold_axes: expected DoF names, got {name!r}")
        if isinstance(self.marker_noise, Mapping):
            object.__setattr__(self, "marker_noise", tuple(sorted(self.marker_noise.items())))
        lock = self.lock
        if isinstance(lock, Mapping):
            lock = tuple(sorted(lock.items()))
        elif isinstance(lock, str):
            lock = ((lock, 0.0),)
        else:
            lock = tuple(sorted((x, 0.0) if isinstance(x, str) else tuple(x) for x in lock))
        object.__setattr__(self, "lock", lock)
        for item in self.lock:
            if len(item) != 2 or not isinstance(item[0], str):
                raise ValueError(f"lock: expected DoF names or (DoF, angle) pairs, got {item!r}")
            v = item[1]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"lock: {item[0]}: the angle must be a number in radians, got {v!r}")
        for label, v in self.marker_noise:
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 and math.isfinite(v)):
                raise ValueError(f"marker_noise: {label}: must be a positive noise SD in metres, got {v!r}")
        bad = [g for g in self.free if g not in GROUPS]
        if bad:
            raise ValueError(f"free: unknown parameter group(s) {', '.join(bad)}; choose from {', '.join(GROUPS)}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss: '{self.loss}' is not one of {', '.join(LOSSES)}")
        for name in ("noise", "loss_scale", "ftol", "atol", "xtol", "gtol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        for name in ("marker", "centre", "axis", "scale"):
            v = getattr(self.priors, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be a positive standard deviation, got {v!r}")
        for name in ("symmetry_scale", "symmetry_centre"):
            v = getattr(self.priors, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and v >= 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be 0 (off) or a positive standard deviation, got {v!r}")
        if self.learn_noise is not None and not isinstance(self.learn_noise, bool):
            raise ValueError(f"learn_noise: must be true, false or None (auto), got {self.learn_noise!r}")
        if not (isinstance(self.outliers, (int, float)) and self.outliers >= 0 and math.isfinite(self.outliers)):
            raise ValueError(f"outliers: must be 0 (off) or a positive number of noise SDs, got {self.outliers!r}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {self.max_iterations!r}")


@dataclass
class State:
    """A point of the problem: coordinates of every frame and the full parameter vector."""

    Z: np.ndarray  # (F, nz): root translation, root rotation increment (0 between steps), angles
    Q: np.ndarray  # (F, 4) root reference quaternions (x, y, z, w)
    p: np.ndarray  # full parameter vector (Parameters.vector() layout)
    # (F, n_balls, 4) reference quaternions of the ball joints kept on SO(3) (Kinematics.balls),
    # whose angles in Z are then increments about them (0 between steps); None: every reference
    # the identity, so that Z holds every joint's absolute angles (how a caller starts a state).
    B: np.ndarray | None = None


@dataclass(frozen=True)
class _Group:
    """Markers of one segment: their rows, and the z / p columns they depend on."""

    rows: np.ndarray  # rows of the per-frame residual vector (3 per marker)
    zcols: np.ndarray  # z columns with a nonzero
    pcols: np.ndarray  # full-p columns with a nonzero
    z_src: np.ndarray  # positions in the dz nonzero vector ...
    z_dst: np.ndarray  # ... and where they go in the flattened (rows, zcols) block
    p_src: np.ndarray
    p_dst: np.ndarray


@dataclass
class Linearization:
    """The Gauss–Newton normal equations in block-arrow form, at one State."""

    cost: float
    A: np.ndarray  # (F, nz, nz)  Σ J_z' J_z per frame
    B: np.ndarray  # (F, nz, n)   Σ J_z' J_p per frame (free parameters)
    C: np.ndarray  # (n, n)       Σ_f J_p' J_p + prior
    gz: np.ndarray  # (F, nz)
    gp: np.ndarray  # (n,)
    a_pattern: np.ndarray | None = None  # (nz, nz) bool: which A_f entries can be nonzero (None: any)
    b_pattern: np.ndarray | None = None  # (nz, n) bool: which B_f entries can be nonzero (None: any)
    jacobian: tuple | None = None  # for Problem.gradient: (d, jz, jp, row weights, layout, prior J, limits on)


def _robust(s: np.ndarray, loss: str, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """ρ(s) and ρ'(s) for squared, noise-normalised residual norms s."""
    if loss == "huber":
        r = np.sqrt(s)
        inside = s <= c2
        c = math.sqrt(c2)
        return np.where(inside, s, 2 * c * r - c2), np.where(inside, 1.0, c / np.maximum(r, 1e-300))
    if loss == "cauchy":
        return c2 * np.log1p(s / c2), 1.0 / (1.0 + s / c2)
    return s, np.ones_like(s)


class Problem:
    """Residuals, cost and block-arrow normal equations of one trial and one model.

    Immutable once built: another loss, base model, noise, set of frames or of observations is a
    new Problem (with_loss, with_base, with_noise, subset, without, with_settings) that shares the
    kinematics and the compiled per-frame functions.  Its arrays are not to be written to."""

    def __init__(self, model: Model, observed: np.ndarray, settings: Settings | None = None,
                 kinematics: Kinematics | None = None, base: Parameters | None = None,
                 progress: Callable[[str], None] | None = None):
        """`observed` (F, n_model_markers, 3) in metres, NaN where a marker is not seen; `progress`
        hears of the one slow step of building (compiling a model structure never seen before)."""
        self._progress = progress
        self._model = model
        self._settings = settings or Settings()
        # Ball joints with a locked coordinate stay on their three angles (the lock holds an angle).
        locked_balls = tuple(j.name for j in model.joints if j.kind == "ball"
                             and any(d in dict(self.settings.lock) for d in j.dofs))
        self._kin = kinematics or build_kinematics(model, euler=locked_balls)
        if any(b.name in locked_balls for b in self.kin.balls):
            self._kin = build_kinematics(model, euler=locked_balls)
        obs = np.asarray(observed, dtype=float)
        nm = len(model.markers)
        if obs.ndim != 3 or obs.shape[1:] != (nm, 3):
            raise ValueError(f"observed: expected (frames, {nm}, 3), got {obs.shape}")
        # Mapped per-frame functions by (kind, frames), shared with subsets (they depend on no data).
        self._mapped: dict[tuple[str, int], tuple] = {}
        self._set_observed(obs)
        # Noise SD of each model marker (m): Settings.noise unless Settings.marker_noise names it.
        self._sigma = np.full(nm, self.settings.noise)
        for label, v in self.settings.marker_noise:
            if label in model.marker_names:
                self._sigma[model.marker_index(label)] = v
        self._base = base or model.parameters()
        # Joint limits, widened by LIMIT_MARGIN: a segment frame's zero may settle a little away
        # from the base model's, and the limits must not fight the data over it.
        self.lower = np.array([d.lower for d in model.dofs]) - LIMIT_MARGIN
        self.upper = np.array([d.upper for d in model.dofs]) + LIMIT_MARGIN
        # Locked coordinates: the same residual with both bounds at the value, always active.
        self.locked = np.zeros(model.n_dofs, dtype=bool)
        self._limit_w = np.full(model.n_dofs, LIMIT_WEIGHT / self.settings.noise)
        for name, value in self.settings.lock:
            k = model.dof_index(name)
            self.locked[k] = True
            self.lower[k] = self.upper[k] = value
            self._limit_w[k] = LOCK_WEIGHT / self.settings.noise
        # The angles of a ball on SO(3) are increments during the solve: no limit applies to them
        # (the rotation has no mirror branch to slide into; limit_notes still read the output angles).
        for b in self.kin.balls:
            self._limit_w[list(b.dofs)] = 0.0
        self._layout()
        self._build_functions()
        # Scratch memory of the solver (large per-frame arrays kept between its runs; see buffers()):
        # like Pinocchio's Data, owned here, never read as a result.
        self._work: dict = {}

    # ------------------------------------------------------------------ what the problem is made of
    @property
    def model(self) -> Model:
        """The subject's model (its structure; the parameters are the state's)."""
        return self._model

    @property
    def settings(self) -> Settings:
        """What is calibrated and how (the problem's options: free groups, noise, priors, loss, locks, held axes)."""
        return self._settings

    @property
    def kin(self) -> Kinematics:
        """The symbolic kinematics the per-frame functions were built from."""
        return self._kin

    @property
    def loss(self) -> str:
        """The robust loss in use ('linear', 'huber' or 'cauchy'; see with_loss)."""
        return self._settings.loss

    @property
    def base(self) -> Parameters:
        """The base model's parameters: the priors' centres (see with_base)."""
        return self._base

    @property
    def sigma(self) -> np.ndarray:
        """(n_markers,) each marker's noise SD (m; see with_noise).  Not to be written to."""
        return self._sigma

    @property
    def observed(self) -> np.ndarray:
        """(F, n_markers, 3) the observed marker positions (m), NaN where not seen or left out (see without)."""
        return self._observed

    @property
    def F(self) -> int:
        """Frames."""
        return self._observed.shape[0]

    @property
    def seen(self) -> np.ndarray:
        """(F, n_markers) bool: which markers are observed (have residual rows) in each frame."""
        return self._seen

    @property
    def target(self) -> np.ndarray:
        """(F, 3 n_markers) the observed positions, 0 where not seen (the per-frame functions' input)."""
        return self._target

    @property
    def n_obs(self) -> int:
        """Observed marker positions (frame, marker pairs)."""
        return self._n_obs

    def _set_observed(self, obs: np.ndarray) -> None:
        self._observed = obs
        self._seen = np.all(np.isfinite(obs), axis=2)  # (F, nm)
        self._target = np.where(self._seen[..., None], obs, 0.0).reshape(obs.shape[0], -1)
        self._n_obs = int(self._seen.sum())

    def buffers(self) -> dict:
        """Scratch memory that calibrate.solve.lm keeps between its runs on this problem (large
        per-frame arrays, whose first touches cost as much as a short run's steps): owned by the
        problem, shared with its copies on the same frames (with_loss, with_base, without), never
        a result.  Runs on one problem and its copies must not overlap in time."""
        return self._work

    def recycle(self, lin: Linearization) -> None:
        """Hand back a Linearization no longer needed: its arrays become the buffers of the next
        linearize(reuse=True) of the same kind (with or without the parameters)."""
        self._work[("lin", lin.jacobian is None or lin.jacobian[2] is None)] = lin

    def with_settings(self, settings: Settings, sigma: np.ndarray | None = None) -> Problem:
        """The same trial, model and prior centres under other settings (e.g. more axes held),
        sharing the kinematics and the compiled functions' cache; `sigma`: the markers' noise SDs
        (m, e.g. learnt from the residuals) instead of the settings'."""
        new = Problem(self.model, self.observed, settings, self.kin, self.base, self._progress)
        if sigma is not None:
            new._sigma = np.array(sigma, dtype=float)
        return new

    def with_loss(self, loss: str) -> Problem:
        """The same problem under another robust loss ('linear', 'huber', 'cauchy'; its scale
        Settings.loss_scale), sharing everything else, the solver's buffers included."""
        new = copy.copy(self)
        new._settings = replace(self._settings, loss=loss)
        return new

    def with_base(self, base: Parameters) -> Problem:
        """The same problem with other prior centres `base` (e.g. with new markers placed), sharing
        everything else, the solver's buffers included."""
        new = copy.copy(self)
        new._base = base
        return new

    def without(self, mask: np.ndarray) -> Problem:
        """The same problem with the observations where `mask` (F, n_markers) is true left out
        (rejected outliers): they lose their rows, as gaps do.  Shares everything else, the
        solver's buffers included."""
        obs = self.observed.copy()
        obs[np.asarray(mask, dtype=bool)] = np.nan
        new = copy.copy(self)
        new._set_observed(obs)
        return new

    def with_noise(self, sigma: np.ndarray) -> Problem:
        """The same problem with other per-marker noise SDs (m; e.g. learnt from the residuals),
        sharing everything else (the observations, compiled functions, prior centres)."""
        sigma = np.asarray(sigma, dtype=float)
        if sigma.shape != self.sigma.shape or not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise ValueError(f"sigma: expected {self.sigma.size} positive noise SDs, got {sigma!r}")
        new = copy.copy(self)
        new._work = {}
        new._sigma = sigma.copy()
        return new

    def subset(self, frames: np.ndarray) -> Problem:
        """The same problem on some of its frames (e.g. an evenly spaced subsample that finds
        the geometry's basin cheaply), sharing the compiled functions."""
        new = copy.copy(self)
        new._work = {}
        new._set_observed(self.observed[np.asarray(frames)])
        return new

    # ------------------------------------------------------------------ layout
    def _layout(self) -> None:
        m, st = self.model, self.settings
        free = set(st.free)
        still = set(st.hold_segments)
        # Locked and held coordinates keep their axes; held segments all their geometry (blocks.py).
        self.layout = ParameterLayout(m, free, {name for name, _ in st.lock} | set(st.hold_axes), still,
                                      self.kin.balls)
        L = self.layout
        self.np_full = L.n_full
        self.axis_dofs = L.axis_dofs  # axes that are calibrated: hinge and universal joints' (never a ball's)
        seg_of = {s.name: i for i, s in enumerate(m.segments)}
        self.marker_segment = np.array([seg_of[mk.segment] for mk in m.markers])
        self.centre_segment = np.array([seg_of[j.parent] for j in m.joints])
        self.free_names = L.free_names
        self.n_free = L.n_free
        self._direct = L.direct  # (free column, p entry) of every free column but the axes' tangents
        self._gauges = self._find_gauges()
        self._urdf = {u.name: u for u in m.urdf_joints}
        # A frame's turn is carried into the segments below only if all they hold is free.
        self._carries = {"centre", "axis", "marker"} <= free
        self._slides = [ji for ji, j in enumerate(m.joints) if j.kind == "hinge" and "centre" in free
                        and j.parent not in still and j.child not in still
                        and ("marker" in free or not np.any(self.marker_segment == m.segment_index(j.child)))]

    def _find_gauges(self, through_held: bool = False) -> list[tuple[int, str]]:
        """Segments whose frame can turn (root: also shift) with no effect on the data, because
        everything expressed in it is free: (segment index, 'rigid' | 'rotation' | 'axis').
        `through_held`: a held axis may be re-expressed in a turned frame (its direction against
        the markers kept; Problem.neutral_gauges), else it blocks the turn as a locked DoF does."""
        m, free = self.model, set(self.settings.free)
        # A held axis is fixed in its parent's frame (and its child's), as a locked coordinate's is.
        locked = {name for name, _ in self.settings.lock} | (set() if through_held else set(self.settings.hold_axes))
        out = []
        into = {j.child: j for j in m.joints}
        still = set(self.settings.hold_segments)  # their geometry cannot turn with a frame

        def held_below(name: str) -> bool:
            """A held or locked DoF (or a held segment) down the hinge and universal chains below `name`."""
            return any(any(d in locked for d in j.dofs) or j.child in still or held_below(j.child)
                       for j in m.joints if j.parent == name and j.kind in ("hinge", "universal"))

        for si, seg in enumerate(m.segments):
            if seg.name in still:  # (a held kid below a ball joint does not block: the ball's angles absorb the turn)
                continue
            has_mk = bool(np.any(self.marker_segment == si))
            kids = [j for j in m.joints if j.parent == seg.name]
            if (has_mk and "marker" not in free) or (kids and "centre" not in free):
                continue
            if any(j.kind in ("hinge", "universal") and "axis" not in free for j in kids):
                continue
            # A locked coordinate cannot absorb a turn of the frame below it, nor turn with a kid's axis.
            if seg.name in into and any(d in locked for d in into[seg.name].dofs):
                continue
            if held_below(seg.name):  # a kid's axis, or the turn carried down (_turn) into a held axis
                continue
            if si == 0:
                out.append((si, "rigid"))
            elif seg.name in into and into[seg.name].kind == "ball":
                out.append((si, "rotation"))
            elif seg.name in into and into[seg.name].kind in ("hinge", "universal") and "axis" in free:
                out.append((si, "axis"))
        return out

    def align_frames(self, p: np.ndarray) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn each free segment frame (see gauge_constraints) to where the priors want it.

        Per segment (parents first), the rotation G (root: and shift t) that best carries the
        base model's markers, joint centres and child hinge axes onto the current ones (weighted
        by the prior SDs; about the hinge axis only for a hinge's child) is taken out of the
        contents: x ← Gᵀ(x − t), and carried through hinge and universal joints into the
        segments below (see _turn), so that the data are unchanged once each turned frame's
        coordinates follow (root pose, a hinge's angle; ball angles are re-solved by the caller).
        Returns the new p and (segment, kind, G, t) per segment."""
        m, L, pr = self.model, self.layout, self.settings.priors
        base = self.base.vector()
        out = p.copy()
        moves = []
        for si, kind in self._gauges:
            s = out[L.scale(si)]
            pts, pts0, wts = [], [], []
            for k in np.flatnonzero(self.marker_segment == si):
                if not self.seen[:, k].any():
                    continue
                sl = L.marker(k)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(1 / pr.marker**2)
            for ji in np.flatnonzero(self.centre_segment == si):
                sl = L.centre(ji)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(1 / pr.centre**2)
            dirs, dirs0, dw = [], [], []
            for ji in np.flatnonzero(self.centre_segment == si):
                j = m.joints[ji]
                if j.kind in ("hinge", "universal"):  # the first axis, in this segment's frame
                    d = m.dof_index(j.dofs[0])
                    if d in self.axis_dofs:
                        u = self._urdf[j.urdf_joints[0]]
                        sl = L.axis(d)
                        dirs.append(u.rotation @ self.axis_direction(out, d))
                        dirs0.append(u.rotation @ (base[sl] / np.linalg.norm(base[sl])))
                        dw.append(1 / pr.axis**2)
            X = np.array(pts + dirs).reshape(-1, 3)
            X0 = np.array(pts0 + dirs0).reshape(-1, 3)
            w = np.array(wts + dw)
            n_pts = len(pts)
            t = np.zeros(3)
            if kind == "rigid" and n_pts:
                wp = w[:n_pts] / w[:n_pts].sum()
                t = wp @ X[:n_pts] - wp @ X0[:n_pts]
                Xc = X.copy()
                Xc[:n_pts] -= t
            else:
                Xc = X
            if kind == "axis":
                j = next(j for j in m.joints if j.child == m.segments[si].name)
                a = self.axis_direction(out, m.dof_index(j.dofs[-1]))
                u0 = X0 - np.outer(X0 @ a, a)
                u1 = Xc - np.outer(Xc @ a, a)
                phi = math.atan2(float(np.sum(w * (np.cross(u0, u1) @ a))), float(np.sum(w * np.sum(u0 * u1, axis=1))))
                K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
                G = np.eye(3) + math.sin(phi) * K + (1 - math.cos(phi)) * K @ K
            else:
                if len(X) < 2:
                    continue
                H = (X0 * w[:, None]).T @ Xc
                U, _, Vt = np.linalg.svd(H)
                D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
                G = Vt.T @ D @ U.T  # G @ x0 ≈ x
            self._turn(out, si, G, t)
            moves.append((si, kind, G, t))
        return out, moves

    def neutral_gauges(self) -> list[tuple[int, str]]:
        """The segment frames that a neutral trial may turn (neutral_frames): the gauges, held axes
        not blocking (a held axis keeps its direction against the markers, re-expressed)."""
        return self._find_gauges(through_held=True)

    def neutral_frames(self, p: np.ndarray, Z: np.ndarray,
                       segments: list[tuple[int, str]]) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn the frames of `segments` (from neutral_gauges; not the root) so that the
        coordinates of the frames Z (F, nz) — a trial in the model's neutral pose — are zero on average:
        below a ball joint, by the mean (chordal) rotation of the joint in those frames; below a
        hinge or universal joint, about its last axis by the mean angle.  The contents are turned
        as in align_frames; returns the new p and (segment, kind, G, 0) per segment."""
        from scipy.spatial.transform import Rotation

        m, fl = self.model, self.layout.frame
        out = p.copy()
        moves = []
        into = {j.child: j for j in m.joints}
        for si, kind in segments:
            j = into[m.segments[si].name]
            if kind == "rotation":
                R = np.broadcast_to(np.eye(3), (Z.shape[0], 3, 3))
                R0 = np.eye(3)
                for u in (self._urdf[n] for n in j.urdf_joints):
                    turn = np.eye(3) if u.dof < 0 else Rotation.from_rotvec(
                        np.outer(Z[:, fl.angle(u.dof)], self.axis_direction(out, u.dof))).as_matrix()
                    R = R @ u.rotation @ turn
                    R0 = R0 @ u.rotation
                U, _, Vt = np.linalg.svd(R.sum(axis=0))
                mean = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
                G = mean.T @ R0
            elif kind == "axis":
                d = m.dof_index(j.dofs[-1])
                G = Rotation.from_rotvec(-float(np.mean(Z[:, fl.angle(d)])) * self.axis_direction(out, d)).as_matrix()
            else:
                continue
            self._turn(out, si, G)
            moves.append((si, kind, G, np.zeros(3)))
        return out, moves

    def _turn(self, out: np.ndarray, si: int, G: np.ndarray, t: np.ndarray | None = None) -> None:
        """Express segment si's contents in its frame turned by G (and shifted by t): in place.

        Below a hinge or universal joint the child's frame then turns too, by Oᵀ G O for the
        joint's fixed origin rotation O, with the joint's axes turned back in their own frames
        (R(Kᵀa, θ) = Kᵀ R(a, θ) K), so its angles are unchanged: the turn is carried down the
        tree until a ball joint, whose angles absorb it."""
        m, L = self.model, self.layout
        shift = np.zeros(3) if t is None else t / out[L.scale(si)]
        for k in np.flatnonzero(self.marker_segment == si):
            sl = L.marker(k)
            out[sl] = G.T @ (out[sl] - shift)
        for ji in np.flatnonzero(self.centre_segment == si):
            sl = L.centre(ji)
            out[sl] = G.T @ (out[sl] - shift)
            j = m.joints[ji]
            if j.kind not in ("hinge", "universal") or not self._carries:
                continue
            K = G
            chain = [self._urdf[n] for n in j.urdf_joints]
            if any(np.any(u.xyz != 0) for u in chain[1:]):
                continue  # an offset inside the joint's chain would not turn with it
            for u in chain:
                K = u.rotation.T @ K @ u.rotation
                if u.dof >= 0:
                    sl = L.axis(u.dof)
                    out[sl] = K.T @ out[sl]
            self._turn(out, m.segment_index(j.child), K)

    def gauge_constraints(self, p: np.ndarray, slides: bool = True) -> np.ndarray:
        """K (n_gauge, n_free): steps with K dp = 0 do not turn (or, for the root, shift) a
        segment's frame against its contents.  Each segment's frame may turn freely with its
        markers, joint centres and child axes turned back (the joint angles absorb it), so only
        the priors would hold that motion; it is a curved valley that slows Levenberg–Marquardt.
        Fixing it keeps each segment's frame oriented as in the start (the base model's
        orientation), which is what the priors choose to first order."""
        m, L = self.model, self.layout
        pr = self.settings.priors
        rows: list[np.ndarray] = []
        for si, kind in self._gauges:
            items: list[tuple[np.ndarray, np.ndarray, float, np.ndarray | None]] = []  # x, cols, weight, basis
            s = p[L.scale(si)]  # free positions are at the subject's scale (see tangent_map)
            for k in np.flatnonzero(self.marker_segment == si):
                items.append((s * p[L.marker(k)], L.cols("marker", k), 1 / pr.marker**2, None))
            for ji in np.flatnonzero(self.centre_segment == si):
                items.append((s * p[L.centre(ji)], L.cols("centre", ji), 1 / pr.centre**2, None))
                for dname in m.joints[ji].dofs:
                    d = m.dof_index(dname)
                    if d in self.axis_dofs:
                        a = self.axis_direction(p, d)
                        items.append((a, L.axis_cols(d), 1 / pr.axis**2, perpendicular_basis(a)))
            if kind == "axis":
                j = next(j for j in m.joints if j.child == m.segments[si].name)
                omegas = [self.axis_direction(p, m.dof_index(j.dofs[-1]))]
            else:
                omegas = list(np.eye(3))
            for w in omegas:
                r = np.zeros(self.n_free)
                for x, cols, wt, B in items:
                    v = wt * cross3(w, x)
                    r[cols] += v if B is None else v @ B
                rows.append(r)
            if kind == "rigid":
                for c in range(3):
                    r = np.zeros(self.n_free)
                    for _, cols, wt, B in items:
                        if B is None:
                            r[cols[c]] += wt
                    rows.append(r)
        # A hinge centre can slide along its axis with the child's contents sliding back: hold
        # it where it starts (the base model's or the seed's point on the axis).
        for ji in self._slides if slides else []:
            j = m.joints[ji]
            d = m.dof_index(j.dofs[0])
            u = self._urdf[j.urdf_joints[0]]
            a = u.rotation @ self.axis_direction(p, d)
            r = np.zeros(self.n_free)
            r[L.cols("centre", ji)] = a
            rows.append(r)
        return np.array(rows, dtype=float).reshape(len(rows), self.n_free)

    def tangent_map(self, p: np.ndarray) -> np.ndarray:
        """T (np_full, n_free): full-parameter change per unit free-parameter change at `p`
        (ParameterLayout.tangent_map)."""
        return self.layout.tangent_map(p)

    def axis_direction(self, p: np.ndarray, d: int) -> np.ndarray:
        """DoF d's axis in `p`, normalised (unit)."""
        return self.layout.axis_direction(p, d)

    def retract_parameters(self, p: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """p moved by the free-parameter step dp, each block on its manifold (ParameterLayout.retract)."""
        return self.layout.retract(p, dp)

    # ------------------------------------------------------------------ CasADi
    def _build_functions(self) -> None:
        m, kin = self.model, self.kin
        nz, nm = m.nz, len(m.markers)
        key = _structure_key(m, kin) if self.settings.compile else None
        cached = _load_compiled(key) if key else None
        self.compiled = cached is not None
        if cached is not None:  # a model of this structure was compiled before: no symbolic work
            (full, pose, resid), (zr, zc, pr, pc, shape) = cached
        else:
            z = ca.SX.sym("z", nz)
            q = ca.SX.sym("refs", kin.n_refs)
            p = ca.SX.sym("p", self.np_full)
            r = ca.SX.sym("r", 3 * nm)
            M, _ = kin.h_ref(z, q, p)
            d = ca.vec(M) - r
            Jz = ca.jacobian(d, z)
            Jp = ca.jacobian(d, p)
            nzs = lambda J: ca.vertcat(*[J.nz[i] for i in range(J.nnz())])  # noqa: E731
            full = ca.Function("calibrate_frame", [z, q, p, r], [d, nzs(Jz), nzs(Jp)])
            pose = ca.Function("calibrate_pose", [z, q, p, r], [d, nzs(Jz)])
            resid = ca.Function("calibrate_resid", [z, q, p, r], [d])
            zr, zc = _pattern(Jz.sparsity())
            pr, pc = _pattern(Jp.sparsity())
            shape = np.array([Jz.size1(), Jz.size2()])
            if key:
                if self._progress is not None and c_compiler() is not None:
                    self._progress("build: compiling the model's C code (once per model structure; cached)")
                comp = _compile([full, pose, resid], key, {"zr": zr, "zc": zc, "pr": pr, "pc": pc, "shape": shape})
                if comp is not None:
                    full, pose, resid = comp
                    self.compiled = True
        self._funcs = {"full": full, "pose": pose, "resid": resid}
        # Per-segment groups from the sparsity patterns.
        self._jz_pattern = (zr, zc, int(shape[0]), int(shape[1]))
        self.groups: list[_Group] = []
        for s in range(len(m.segments)):
            mk = np.flatnonzero(self.marker_segment == s)
            if mk.size == 0:
                continue
            rows = (3 * mk[:, None] + np.arange(3)).ravel()
            row_pos = {int(x): i for i, x in enumerate(rows)}
            zsel = np.isin(zr, rows)
            psel = np.isin(pr, rows)
            zcols = np.unique(zc[zsel])
            pcols = np.unique(pc[psel])
            zpos = {int(c): i for i, c in enumerate(zcols)}
            ppos = {int(c): i for i, c in enumerate(pcols)}
            z_src = np.flatnonzero(zsel)
            p_src = np.flatnonzero(psel)
            z_dst = np.array([row_pos[int(zr[i])] * zcols.size + zpos[int(zc[i])] for i in z_src], dtype=int)
            p_dst = np.array([row_pos[int(pr[i])] * pcols.size + ppos[int(pc[i])] for i in p_src], dtype=int)
            self.groups.append(_Group(rows, zcols, pcols, z_src, z_dst, p_src, p_dst))
        self._layout_z = group_layout(self.groups)

    def frame_evaluator(self, p: np.ndarray) -> _FrameEvaluator:
        """One frame's (markers (3 n_markers,), d markers/dz (3 n_markers, nz)) at fixed full
        parameters `p`, through the compiled per-frame function (as Kinematics.frame_evaluator)."""
        return _FrameEvaluator(self._funcs["pose"], np.asarray(p, dtype=float), self._jz_pattern, self.kin.n_refs)

    def _run(self, kind: str, state: State, out: tuple | None = None) -> list[np.ndarray]:
        """Evaluate the per-frame function `kind` over every frame, EVAL_BLOCK frames per mapped
        call (a map's construction grows with its size, and costs ~15 ms: a short last block is
        padded with copies of its last frame so that one map size serves every problem), into
        numpy arrays (F, nnz_out): those of `out` where their shapes fit (buffers no longer
        needed), else fresh ones."""
        F = state.Z.shape[0]
        f0 = self._funcs[kind]
        outs = [np.empty((F, f0.nnz_out(i))) for i in range(f0.n_out())]
        for i, o in enumerate(out or ()):
            if i < len(outs) and isinstance(o, np.ndarray) and o.shape == outs[i].shape:
                outs[i] = o
        Z = np.ascontiguousarray(state.Z, dtype=float)
        Q = np.ascontiguousarray(self.kin.refs(state.Q, state.B), dtype=float)
        P = np.tile(np.asarray(state.p, dtype=float), EVAL_BLOCK)
        for s in range(0, F, EVAL_BLOCK):
            e = min(F, s + EVAL_BLOCK)
            n = e - s
            size = EVAL_BLOCK if n > EVAL_PAD else n
            key = (kind, size)
            if key not in self._mapped:
                fm = f0.map(size, "thread", 2)
                self._mapped[key] = (fm, *fm.buffer())
            _, buf, ev = self._mapped[key]
            ins = [Z[s:e], Q[s:e], self.target[s:e]]
            res = [o[s:e] for o in outs]
            if size > n:
                ins = [np.concatenate([a, np.repeat(a[-1:], size - n, axis=0)]) for a in ins]
                res = [np.empty((size, o.shape[1])) for o in outs]
            for i, a in enumerate((ins[0], ins[1], P[:size * self.np_full], ins[2])):
                buf.set_arg(i, memoryview(a))
            for i, o in enumerate(res):
                buf.set_res(i, memoryview(o))
            ev()
            if size > n:
                for o, r in zip(outs, res, strict=True):
                    o[s:e] = r[:n]
        return outs

    # ------------------------------------------------------------------ residuals
    def marker_residuals(self, state: State) -> np.ndarray:
        """(F, n_markers, 3) model minus observed marker positions (m); NaN where not seen."""
        d = self._run("resid", state)[0].reshape(self.F, -1, 3)
        return np.where(self.seen[..., None], d, np.nan)

    def _weights(self, d: np.ndarray) -> tuple[float, np.ndarray]:
        """Data cost and per-(frame, marker) row weights sqrt(ρ')/σ (0 where not seen)."""
        st = self.settings
        sigma = self.sigma
        s = np.where(self.seen, np.sum(d.reshape(self.F, -1, 3) ** 2, axis=2), 0.0) / sigma**2
        rho, drho = _robust(s, st.loss, st.loss_scale**2)
        cost = 0.5 * float(np.sum(rho[self.seen]))
        w = np.where(self.seen, np.sqrt(drho) / sigma, 0.0)
        return cost, w

    def _prior_centres(self) -> tuple[np.ndarray, tuple]:
        """The base model's parameter vector and its left/right pairs (symmetry_pairs), kept while
        `base` is the same object (prior runs at every cost evaluation)."""
        cached = self.__dict__.get("_prior_cache")
        if cached is None or cached[0] is not self.base:
            base = self.base.vector()
            cached = (self.base, base, symmetry_pairs(self.model, base[self.layout.group("centre")].reshape(-1, 3)))
            self._prior_cache = cached
        return cached[1], cached[2]

    def prior(self, p: np.ndarray, T: np.ndarray | None = None,
              jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Prior residuals and their Jacobian (n_prior, n_free) at full parameters `p`, through the
        free-parameter map `T` (default: tangent_map(p)); no Jacobian (None) if not `jacobian`."""
        st, m, L = self.settings, self.model, self.layout
        free = set(st.free)
        base, (seg_pairs, joint_pairs, mirror) = self._prior_centres()
        scale = p[L.scales]
        res: list[np.ndarray] = []
        jac: list[np.ndarray] = []  # d residual / d p_full

        def block(group: str, count: int, seg_of: np.ndarray, sigma: float) -> None:
            idx = L.entries(group)  # (count, 3) full indices
            s = scale[seg_of][:, None]
            diff = p[idx] - base[idx]
            res.append((s * diff / sigma).ravel())
            if not jacobian:
                return
            J = np.zeros((3 * count, self.np_full))
            rows = np.arange(3 * count)
            J[rows, idx.ravel()] = np.repeat(scale[seg_of], 3) / sigma
            J[rows, L.scale(np.repeat(seg_of, 3))] = diff.ravel() / sigma
            jac.append(J)

        if "marker" in free:
            block("marker", len(m.markers), self.marker_segment, st.priors.marker)
        if "centre" in free:
            block("centre", len(m.joints), self.centre_segment, st.priors.centre)
        for d in self.axis_dofs:
            sl = L.axis(d)
            res.append((p[sl] - base[sl] / np.linalg.norm(base[sl])) / st.priors.axis)
            if jacobian:
                J = np.zeros((3, self.np_full))
                J[:, sl] = np.eye(3) / st.priors.axis
                jac.append(J)
        if "scale" in free:
            ns = len(m.segments)
            res.append((scale - base[L.scales]) / st.priors.scale)
            if jacobian:
                J = np.zeros((ns, self.np_full))
                J[np.arange(ns), np.r_[L.scales]] = 1.0 / st.priors.scale
                jac.append(J)
        # Left/right symmetry (Priors.symmetry_scale, symmetry_centre): a left segment's scale against
        # its right partner's, a left joint centre (at its parent's scale) against its right partner's
        # mirrored through the sagittal plane, both relative to the base model's own asymmetry.
        sd = st.priors.symmetry_scale
        if "scale" in free and sd > 0 and seg_pairs:
            a, b = np.array(seg_pairs).T
            res.append(((scale[a] - scale[b]) - (base[L.scale(a)] - base[L.scale(b)])) / sd)
            if jacobian:
                J = np.zeros((a.size, self.np_full))
                J[np.arange(a.size), L.scale(a)] = 1.0 / sd
                J[np.arange(a.size), L.scale(b)] = -1.0 / sd
                jac.append(J)
        sd = st.priors.symmetry_centre
        if "centre" in free and sd > 0 and joint_pairs:
            for jl, jr in joint_pairs:
                sa, sb = int(self.centre_segment[jl]), int(self.centre_segment[jr])
                il, ir = L.entries("centre", [jl, jr])
                res.append((scale[sa] * p[il] - mirror * (scale[sb] * p[ir]) - (base[il] - mirror * base[ir])) / sd)
                if not jacobian:
                    continue
                J = np.zeros((3, self.np_full))
                J[np.arange(3), il] = scale[sa] / sd
                J[np.arange(3), ir] = -mirror * scale[sb] / sd
                J[:, L.scale(sa)] += p[il] / sd
                J[:, L.scale(sb)] -= mirror * p[ir] / sd
                jac.append(J)
        if not res:
            return np.zeros(0), np.zeros((0, self.n_free))
        if not jacobian:
            return np.concatenate(res), None
        T = self.tangent_map(p) if T is None else T
        return np.concatenate(res), np.vstack(jac) @ T

    def limits(self, Z: np.ndarray) -> np.ndarray:
        """Joint-limit residuals (F, n_dofs): LIMIT_WEIGHT/σ × how far each angle lies outside its
        range (zero inside it).  They never bias a pose within the range of motion; they keep a
        frame from sliding into a mirror-image branch or a full turn while the geometry is poor."""
        th = self.layout.frame.angles(Z)
        return self._limit_w * (th - np.clip(th, self.lower, self.upper))

    def _limit_active(self, lim: np.ndarray) -> np.ndarray:
        """(F, n_dofs) where a limit residual has a Jacobian row: outside a limit, or locked."""
        return (lim != 0) | self.locked

    def cost(self, state: State) -> float:
        """Total cost (markers + joint limits + priors) at `state`."""
        d = self._run("resid", state)[0]
        c, _ = self._weights(d)
        r, _ = self.prior(state.p, jacobian=False)
        lim = self.limits(state.Z)
        return c + 0.5 * float(r @ r) + 0.5 * float(np.sum(lim**2))

    # ------------------------------------------------------------------ normal equations
    def linearize(self, state: State, with_parameters: bool = True,
                  reuse: Linearization | bool | None = None) -> Linearization:
        """Cost and block-arrow normal equations at `state` (weights from the robust loss).
        `reuse`: a Linearization no longer needed, whose arrays are overwritten (saves allocating
        the large B afresh at every iteration); True: the one last handed back by recycle() (the
        solver's last run on this problem), if any.

        The per-segment Jacobian blocks are gathered and multiplied frame by frame in compiled
        loops (calibrate.solve.assembly): the time is linear in the frames."""
        F, nz = self.F, self.model.nz
        if reuse is True:
            reuse = self._work.pop(("lin", not with_parameters), None)
        elif reuse is False:
            reuse = None
        old = reuse.jacobian[:3] if reuse is not None and reuse.jacobian is not None else None  # (d, jz, jp)
        if with_parameters:
            d, jz, jp = self._run("full", state, old)
        else:
            (d, jz), jp = self._run("pose", state, old), None
        cost, w = self._weights(d)
        wrow = np.repeat(w, 3, axis=1)  # (F, 3 nm)
        n = self.n_free if with_parameters else 0
        A = reuse.A if reuse is not None and reuse.A.shape == (F, nz, nz) else np.empty((F, nz, nz))
        B = reuse.B if reuse is not None and reuse.B.shape == (F, nz, n) else np.empty((F, nz, n))
        gz = np.empty((F, nz))
        pl = parameter_layout(self.groups, self.tangent_map(state.p)) if with_parameters else None
        C, gp = assemble(d, wrow, jz, jp, self._layout_z, pl, A, B, gz, n)
        a_pat = np.eye(nz, dtype=bool)
        b_pat = np.zeros((nz, n), dtype=bool)
        for k, g in enumerate(self.groups):
            a_pat[np.ix_(g.zcols, g.zcols)] = True
            if pl is not None:
                b_pat[np.ix_(g.zcols, pl.fcols[pl.fc_off[k]:pl.fc_off[k + 1]])] = True
        lim = self.limits(state.Z)
        out = self._limit_active(lim)
        if out.any():
            cost += 0.5 * float(np.sum(lim**2))
            f, d_ = np.nonzero(out)
            k = self._limit_w[d_]
            c = self.layout.frame.angle(d_)
            A[f, c, c] += k * k
            gz[f, c] += k * lim[f, d_]
        r, Jr = self.prior(state.p)
        cost += 0.5 * float(r @ r)
        if with_parameters:
            C += Jr.T @ Jr
            gp += Jr.T @ r
        return Linearization(cost, A, B, C, gz, gp, a_pat, b_pat, (d, jz, jp, wrow, pl, Jr, out))

    def residual_parts(self, state: State) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The residuals at `state`, unweighted markers (F, 3 n_markers; 0 where not seen), joint
        limits (F, n_dofs) and priors: what the geodesic acceleration differentiates twice."""
        d = self._run("resid", state)[0]
        r, _ = self.prior(state.p, jacobian=False)
        return np.where(np.repeat(self.seen, 3, axis=1), d, 0.0), self.limits(state.Z), r

    def gradient(self, lin: Linearization, d: np.ndarray, lim: np.ndarray,
                 r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """J'ρ for residuals ρ = (markers d (F, 3 n_markers) unweighted, limits lim, priors r), with
        the Jacobian J and weights of `lin`: (g_z (F, nz), g_p (n,))."""
        _, jz, jp, wrow, pl, Jr, on = lin.jacobian
        F, nz = lin.gz.shape
        n = lin.gp.size
        gz = np.empty((F, nz))
        _, gp = assemble(np.ascontiguousarray(d), wrow, jz, jp, self._layout_z, pl, lin.A, lin.B, gz, n,
                         gradient_only=True)
        if on.any():
            f, k = np.nonzero(on)
            gz[f, self.layout.frame.angle(k)] += self._limit_w[k] * lim[f, k]
        if n:
            gp = gp + Jr.T @ r
        return gz, gp

    def residual_vector(self, state: State) -> np.ndarray:
        """Every residual (weighted markers frame by frame, joint limits, priors) as one vector
        whose squared norm is twice the cost (linear loss)."""
        d = self._run("resid", state)[0]
        _, w = self._weights(d)
        r, _ = self.prior(state.p, jacobian=False)
        return np.concatenate([(d * np.repeat(w, 3, axis=1)).ravel(), self.limits(state.Z).ravel(), r])

    def full_jacobian(self, state: State, T: np.ndarray | None = None):
        """residual_vector(state) and its sparse Jacobian (scipy CSR) over [z_1 … z_F, x] where
        p = p(state) + T x (T: default tangent_map): for comparisons with general-purpose
        solvers; ours never forms it."""
        from scipy import sparse

        F, nz = self.F, self.model.nz
        d, jz, jp = self._run("full", state)
        cost, w = self._weights(d)
        wrow = np.repeat(w, 3, axis=1)
        rows3 = d.shape[1]
        T = self.tangent_map(state.p) if T is None else T
        blocks_r, blocks_c, blocks_v = [], [], []
        for g in self.groups:
            wg = wrow[:, g.rows][:, :, None]
            Jz = np.zeros((F, g.rows.size * g.zcols.size))
            Jz[:, g.z_dst] = jz[:, g.z_src]
            Jz = Jz.reshape(F, g.rows.size, g.zcols.size) * wg
            fr = np.arange(F)[:, None, None]
            blocks_r.append(np.broadcast_to(fr * rows3 + g.rows[None, :, None], Jz.shape).ravel())
            blocks_c.append(np.broadcast_to(fr * nz + g.zcols[None, None, :], Jz.shape).ravel())
            blocks_v.append(Jz.ravel())
            Tg = T[g.pcols]
            fcols = np.flatnonzero(np.any(Tg != 0, axis=0))
            Jp = np.zeros((F, g.rows.size * g.pcols.size))
            Jp[:, g.p_dst] = jp[:, g.p_src]
            Jp = (Jp.reshape(F, g.rows.size, g.pcols.size) @ Tg[:, fcols]) * wg
            blocks_r.append(np.broadcast_to(fr * rows3 + g.rows[None, :, None], Jp.shape).ravel())
            blocks_c.append(np.broadcast_to(F * nz + fcols[None, None, :], Jp.shape).ravel())
            blocks_v.append(Jp.ravel())
        lim = self.limits(state.Z)
        nd = lim.shape[1]
        lf, ld = np.nonzero(self._limit_active(lim))
        blocks_r.append(F * rows3 + lf * nd + ld)
        blocks_c.append(lf * nz + self.layout.frame.angle(ld))
        blocks_v.append(self._limit_w[ld])
        r, Jr = self.prior(state.p, T)
        pr, pc = np.nonzero(Jr)
        blocks_r.append(F * rows3 + F * nd + pr)
        blocks_c.append(F * nz + pc)
        blocks_v.append(Jr[pr, pc])
        e = np.concatenate([(d * wrow).ravel(), lim.ravel(), r])
        J = sparse.csr_matrix((np.concatenate(blocks_v), (np.concatenate(blocks_r), np.concatenate(blocks_c))),
                              shape=(e.size, F * nz + self.n_free))
        return e, J


def symmetry_pairs(model: Model, centres: np.ndarray) -> tuple[list[tuple[int, int]], list[tuple[int, int]],
                                                               np.ndarray]:
    """Left/right partners by name (``X_l`` / ``X_r``): (segment index pairs, joint index pairs, mirror),
    the mirror a diagonal (3,) of ±1 that reflects a position through the sagittal plane: the lateral
    axis is the one along which the base model's paired joint centres `centres` (n_joints, 3) differ most
    (y in models/human.urdf, whose segment frames are all parallel in the neutral pose)."""
    def pairs(names: list[str]) -> list[tuple[int, int]]:
        at = {n: i for i, n in enumerate(names)}
        return [(i, at[n[:-2] + "_r"]) for i, n in enumerate(names) if n.endswith("_l") and n[:-2] + "_r" in at]

    seg = pairs([s.name for s in model.segments])
    jnt = pairs([j.name for j in model.joints])
    mirror = np.ones(3)
    if jnt:
        spread = np.sum([np.abs(centres[a] - centres[b]) for a, b in jnt], axis=0)
        mirror[int(np.argmax(spread))] = -1.0
    else:
        mirror[1] = -1.0
    return seg, jnt, mirror


class _FrameEvaluator:
    """Evaluates the per-frame 'pose' function (observed markers set to zero, so its residual is
    the model markers) into preallocated memory; the Jacobian nonzeros are spread into a dense,
    reused (3 n_markers, nz) array.  Outputs are overwritten by the next call."""

    def __init__(self, f: ca.Function, p: np.ndarray, pattern: tuple[np.ndarray, np.ndarray, int, int],
                 n_refs: int = 4):
        rows, cols, n_rows, nz = pattern
        self._f = f  # keep the Function alive while its buffer is used
        self._buf, self._eval = f.buffer()
        self._z, self._q, self._p, self._r = np.zeros(nz), np.zeros(n_refs), p.copy(), np.zeros(n_rows)
        self.markers = np.zeros(n_rows)
        self._jnz = np.zeros(rows.size)
        self.jacobian = np.zeros((n_rows, nz))
        self._flat = rows * nz + cols
        for i, a in enumerate((self._z, self._q, self._p, self._r)):
            self._buf.set_arg(i, memoryview(a))
        self._buf.set_res(0, memoryview(self.markers))
        self._buf.set_res(1, memoryview(self._jnz))

    def __call__(self, z: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._z[:] = z
        self._q[:] = q_ref
        self._eval()
        self.jacobian.reshape(-1)[self._flat] = self._jnz
        return self.markers, self.jacobian


def _pattern(sp: ca.Sparsity) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of every nonzero of a CasADi sparsity, in nonzero order (column-major)."""
    colind = np.asarray(sp.colind())
    row = np.asarray(sp.row())
    col = np.repeat(np.arange(sp.size2()), np.diff(colind))
    return row, col


def _structure_key(model: Model, kin: Kinematics) -> str | None:
    """A digest of everything the per-frame functions are built from: the model's kinematic
    structure (tree, fixed rotations and offsets, which parameter each origin reads) and the code
    that builds them, so that a cached build is reused exactly when it would come out the same.
    None without a C compiler (nothing to cache)."""
    if c_compiler() is None:
        return None
    h = hashlib.sha256(f"{ca.__version__} -O1 {model.root} {model.nz} {len(model.markers)}".encode())
    for src in (Path(__file__), Path(__file__).parent.parent / "model" / "kinematics.py",
                Path(__file__).parent.parent / "model" / "blocks.py"):
        h.update(src.read_bytes())
    h.update(repr([s.name for s in model.segments]).encode())
    h.update(repr([(b.name, b.axes.tolist()) for b in kin.balls]).encode())
    for u in model.urdf_joints:
        fixed_xyz = u.role not in ("centre", "marker")
        h.update(repr((u.parent_link, u.child_link, u.owner, u.role, u.index, u.dof)).encode())
        h.update(np.asarray(u.rotation, dtype=float).tobytes())
        if fixed_xyz:
            h.update(np.asarray(u.xyz, dtype=float).tobytes())
    return h.hexdigest()[:20]


def _load_compiled(key: str) -> tuple[list[ca.Function], tuple] | None:
    """The compiled per-frame functions and their Jacobian patterns cached under `key`, or None."""
    so, npz = cache_dir() / f"frame_{key}.so", cache_dir() / f"frame_{key}.npz"
    if not (so.exists() and npz.exists()):
        return None
    try:
        with np.load(npz) as z:
            patterns = (z["zr"], z["zc"], z["pr"], z["pc"], z["shape"])
        return [ca.external(n, str(so)) for n in ("calibrate_frame", "calibrate_pose", "calibrate_resid")], patterns
    except (OSError, RuntimeError, KeyError, ValueError):
        return None


def _compile(funcs: list[ca.Function], key: str, patterns: dict[str, np.ndarray]) -> list[ca.Function] | None:
    """Generate C for `funcs`, compile it, keep it (with the Jacobian `patterns` beside it) in the
    cache under `key`, and load it.

    Returns None (the caller then keeps CasADi's virtual machine) when there is no C
    compiler or the compile fails: compiling is an optimisation, never a requirement.
    """
    cc = c_compiler()
    if cc is None:
        return None
    try:
        cache = cache_dir()
        cache.mkdir(parents=True, exist_ok=True)
        so = cache / f"frame_{key}.so"
        with tempfile.TemporaryDirectory() as tmp:
            # One translation unit per function, compiled side by side (the per-frame function with
            # its Jacobians takes most of the time), then linked into one library.  -Og: on this
            # straight-line code it compiles in 60 % of -O1's time and runs within ~5 % of it.
            objs, jobs = [], []
            for f in funcs:
                cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
                cg.add(f)
                cg.generate(tmp + os.sep)
                src, obj = Path(tmp) / f"{f.name()}.c", Path(tmp) / f"{f.name()}.o"
                objs.append(str(obj))
                jobs.append(subprocess.Popen([cc, "-Og", "-fPIC", "-c", str(src), "-o", str(obj)],
                                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            failed = [j.wait(timeout=600) for j in jobs]
            if any(failed):
                raise RuntimeError("C compile failed")
            part = cache / f".frame_{key}.{os.getpid()}.so"
            subprocess.run([cc, "-shared", *objs, "-o", str(part)], check=True, capture_output=True, timeout=600)
            side = cache / f".frame_{key}.{os.getpid()}.npz"
            with open(side, "wb") as fh:
                np.savez(fh, **patterns)
            os.replace(part, so)
            os.replace(side, cache / f"frame_{key}.npz")
        return [ca.external(f.name(), str(so)) for f in funcs]
    except (OSError, subprocess.SubprocessError, RuntimeError):
        return None
