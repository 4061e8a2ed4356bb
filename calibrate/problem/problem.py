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
import math
from collections.abc import Callable
from dataclasses import replace
from typing import Generic, TypeVar

import numpy as np

from calibrate.problem.codegen import CodegenMixin, is_compiled
from calibrate.problem.gauge import GaugeMixin
from calibrate.problem.options import ProblemOptions
from calibrate.problem.priors import PriorsMixin
from calibrate.problem.settings import Settings
from calibrate.problem.state import Linearization, State

from ..model.blocks import ParameterLayout
from ..model.kinematics import Kinematics, build_kinematics, locked_balls
from ..model.model import Model, Parameters
from ..solve.assembly import ParameterLayout as ColumnLayout
from ..solve.assembly import assemble, parameter_layout, parameter_pattern, y_pattern_of

T = TypeVar("T")

ALL = slice(None)  # every frame (the `frames` argument of the per-frame evaluations)
COST_FRAMES = 4096  # frames whose residuals Problem.cost forms at once


LIMIT_WEIGHT = 1.0  # m of marker error per rad beyond a joint limit (as in calibrate.solve.ik)


LOCK_WEIGHT = 100.0  # m of marker error per rad away from a locked coordinate's value (Settings.lock)


LIMIT_MARGIN = math.radians(15.0)  # the limits of the global problem are this much wider than the model's


def _checked_weight(weight: np.ndarray, n: int) -> np.ndarray | None:
    """Frame weights as a float array of `n` positive numbers (None when every one is 1)."""
    weight = np.asarray(weight, dtype=float)
    if weight.shape != (n,) or not np.all(np.isfinite(weight) & (weight > 0)):
        raise ValueError(f"frame weights: expected {n} positive numbers, got shape {weight.shape}")
    return None if np.all(weight == 1.0) else weight


def compiled_kinematics(kin: Kinematics, compile: bool = True) -> Kinematics:
    """`kin` whose per-frame evaluator (Kinematics.frame_evaluator with reference=True, what frame-wise
    inverse kinematics calls at every step) runs the compiled per-frame function of its model's structure
    (calibrate.problem.codegen: compiled once per structure and kept on disk) instead of CasADi's virtual
    machine; `kin` itself without a C compiler.  For work that fits the same model to many trials or
    labellings (calibrate.track: 100+ frame-wise fits), where one compile pays many times over.  `compile`
    false: only where that code is in the cache already (a subject's calibration left it there), as for one
    trial's fit (calibrate ik), which a compile of seconds would not pay for."""
    if kin.compiled is not None or not (compile or is_compiled(kin.model, kin)):
        return kin
    problem = Problem(kin.model, np.full((1, len(kin.model.markers), 3), np.nan), None, kin)
    return replace(kin, compiled=problem.frame_evaluator) if problem.compiled else kin


def _problem_options(settings: ProblemOptions | Settings | None) -> ProblemOptions:
    """The problem's options of `settings` (its Settings.problem view if it is the user's Settings)."""
    if settings is None:
        return ProblemOptions()
    return settings.problem if isinstance(settings, Settings) else settings


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


class Frozen(Generic[T]):
    """An attribute of a Problem that is set while it is built (as `_<name>`) and read-only afterwards."""

    def __init__(self, doc: str):
        self.__doc__ = doc

    def __set_name__(self, owner: type, name: str) -> None:
        self.name, self.attr = name, "_" + name

    def __get__(self, obj: object, owner: type | None = None) -> T:
        return self if obj is None else getattr(obj, self.attr)

    def __set__(self, obj: object, value: object) -> None:
        raise AttributeError(f"{self.name}: a Problem does not change once built; make a new one (with_* methods)")


class Problem(GaugeMixin, PriorsMixin, CodegenMixin):
    """Residuals, cost and block-arrow normal equations of one trial and one model.

    Immutable once built: another loss, base model, noise, set of frames or of observations is a
    new Problem (with_loss, with_base, with_noise, subset, without, with_settings) that shares the
    kinematics and the compiled per-frame functions.  Its arrays are not to be written to."""

    def __init__(self, model: Model, observed: np.ndarray, settings: ProblemOptions | Settings | None = None,
                 kinematics: Kinematics | None = None, base: Parameters | None = None,
                 progress: Callable[[str], None] | None = None):
        """`observed` (F, n_model_markers, 3) in metres, NaN where a marker is not seen; `progress`
        hears of the one slow step of building (compiling a model structure never seen before).
        `settings`: the problem's options, or the user's Settings, of which it keeps only their
        problem's view (Settings.problem: never the solver's or the pipeline's options)."""
        self._progress = progress
        self._model = model
        self._settings = _problem_options(settings)
        # Ball joints with a locked coordinate stay on their three angles (the lock holds an angle).
        euler = locked_balls(model, dict(self.settings.lock))
        self._kin = kinematics or build_kinematics(model, euler=euler)
        if any(b.name in euler for b in self.kin.balls):
            self._kin = build_kinematics(model, euler=euler)
        obs = np.asarray(observed, dtype=float)
        nm = len(model.markers)
        if obs.ndim != 3 or obs.shape[1:] != (nm, 3):
            raise ValueError(f"observed: expected (frames, {nm}, 3), got {obs.shape}")
        # Mapped per-frame functions by (kind, frames), shared with subsets (they depend on no data).
        self._mapped: dict[tuple, tuple] = {}  # (kind, frames): the map; (kind, frames, part): its buffer
        self._set_observed(obs)
        self._frame_weight: np.ndarray | None = None  # (F,) see frame_weight; None: every frame counts once
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
    model = Frozen[Model]("The subject's model (its structure; the parameters are the state's).")
    settings = Frozen[ProblemOptions]("The problem's options: free groups, noise, priors, loss, locks, held axes.")
    kin = Frozen[Kinematics]("The symbolic kinematics the per-frame functions were built from.")
    base = Frozen[Parameters]("The base model's parameters: the priors' centres (see with_base).")
    sigma = Frozen[np.ndarray]("(n_markers,) each marker's noise SD (m; see with_noise).")
    observed = Frozen[np.ndarray]("(F, n_markers, 3) observed marker positions (m), NaN where not seen or left out.")
    seen = Frozen[np.ndarray]("(F, n_markers) bool: which markers are observed (have residual rows) in each frame.")
    target = Frozen[np.ndarray]("(F, 3 n_markers) the observed positions, 0 where not seen (per-frame input).")
    n_obs = Frozen[int]("Observed marker positions (frame, marker pairs).")
    unseen = Frozen[np.ndarray]("(n_markers,) bool: markers no frame of the trial shows (held at their offsets).")
    jz_pattern = Frozen[tuple]("(rows, cols, n_rows, nz) of the per-frame d markers / dz Jacobian's nonzeros.")

    @property
    def loss(self) -> str:
        """The robust loss in use ('linear', 'huber' or 'cauchy'; see with_loss)."""
        return self._settings.loss

    @property
    def F(self) -> int:
        """Frames."""
        return self._observed.shape[0]

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

    def with_settings(self, settings: ProblemOptions | Settings, sigma: np.ndarray | None = None) -> Problem:
        """The same trial, model, prior centres and frame weights under other options (e.g. more axes held),
        sharing the kinematics and the compiled functions' cache; `sigma`: the markers' noise SDs
        (m, e.g. learnt from the residuals) instead of the settings'."""
        new = Problem(self.model, self.observed, settings, self.kin, self.base, self._progress)
        if sigma is not None:
            new._sigma = np.array(sigma, dtype=float)
        new._frame_weight = self._frame_weight
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
        return self.with_observed(obs)

    def with_observed(self, observed: np.ndarray) -> Problem:
        """The same problem with other observations (F, n_markers, 3; NaN: not seen) in the same frames,
        e.g. rejected positions restored; shares everything else."""
        observed = np.asarray(observed, dtype=float)
        if observed.shape != self.observed.shape:
            raise ValueError(f"observed: expected shape {self.observed.shape}, got {observed.shape}")
        new = copy.copy(self)
        new._set_observed(observed.copy())
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

    def subset(self, frames: np.ndarray, weight: np.ndarray | None = None) -> Problem:
        """The same problem on some of its frames (e.g. an evenly spaced subsample that finds
        the geometry's basin cheaply), sharing the compiled functions.  `weight` (one per frame of
        `frames`): their frame_weight; None: as in this problem."""
        frames = np.asarray(frames)
        new = copy.copy(self)
        new._work = {}
        new._set_observed(self.observed[frames])
        if weight is not None:
            new._frame_weight = _checked_weight(weight, frames.size)
        elif self._frame_weight is not None:
            new._frame_weight = self._frame_weight[frames]
        return new

    def with_frame_weight(self, weight: np.ndarray | None) -> Problem:
        """The same problem with each frame's markers counted `weight` (F,) times (frame_weight; None:
        once each), sharing everything else."""
        new = copy.copy(self)
        new._work = {}
        new._frame_weight = None if weight is None else _checked_weight(weight, self.F)
        return new

    @property
    def frame_weight(self) -> np.ndarray | None:
        """(F,) how much each frame's markers count in the cost and the normal equations (their squared
        residuals times this): a static trial's frames repeat one pose, and their errors with it, so
        together may count as a few frames (Settings.still_weight), not as many
        as the walk's; None: every frame once.  The joint limits count once per frame."""
        return self._frame_weight

    # ------------------------------------------------------------------ layout
    def _layout(self) -> None:
        m, st = self.model, self.settings
        free = set(st.free)
        still = set(st.hold_segments)
        # Locked and held coordinates keep their axes; held segments all their geometry (blocks.py).
        # A marker no frame shows has no residual: only its prior would move it (to its base offset,
        # where it starts), and as free columns it would only widen every step's Schur complement (the
        # 67 markers of Rajagopal2016.osim absent from its example trials: 201 of 383 columns).  Held.
        self._unseen = ~self._seen.any(axis=0)
        self.layout = ParameterLayout(m, free, {name for name, _ in st.lock} | set(st.hold_axes), still,
                                      self.kin.balls, [m.markers[k].name for k in np.flatnonzero(self._unseen)])
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


    # ------------------------------------------------------------------ residuals
    def marker_residuals(self, state: State) -> np.ndarray:
        """(F, n_markers, 3) model minus observed marker positions (m); NaN where not seen."""
        d = self._run("resid", state)[0].reshape(self.F, -1, 3)
        return np.where(self.seen[..., None], d, np.nan)

    def _weights(self, d: np.ndarray, frames: slice = ALL) -> tuple[float, np.ndarray]:
        """Data cost and per-(frame, marker) row weights sqrt(ρ')/σ (0 where not seen) of the
        residuals `d` of `frames`."""
        st = self.settings
        sigma = self.sigma
        seen = self.seen[frames]
        # |d|² per marker as x² + y² + z², in the order np.sum(…, axis=2) adds them (the same bits) but
        # 10x sooner: numpy's reduction over an axis of 3 is slow.
        sq = d.reshape(seen.shape[0], -1, 3) ** 2
        s = np.where(seen, sq[..., 0] + sq[..., 1] + sq[..., 2], 0.0) / sigma**2
        rho, drho = _robust(s, st.loss, st.loss_scale**2)
        if self._frame_weight is not None:
            fw = self._frame_weight[frames][:, None]
            rho, drho = rho * fw, drho * fw
        cost = 0.5 * float(np.sum(rho[seen]))
        w = np.where(seen, np.sqrt(drho) / sigma, 0.0)
        return cost, w


    def cost(self, state: State) -> float:
        """Total cost (markers + joint limits + priors) at `state`.  The residuals are formed COST_FRAMES
        frames at a time: a long trial's residual array would not stay in the cache (100 000 frames:
        94 MB, read by every step's cost 2.3 times slower per frame than 10 000 frames')."""
        c, out = 0.0, None
        for a in range(0, self.F, COST_FRAMES):
            sel = slice(a, min(self.F, a + COST_FRAMES))
            out = self._run("resid", state, out, sel)
            c += self._weights(out[0], sel)[0]
        r, _ = self.prior(state.p, jacobian=False)
        lim = self.limits(state.Z)
        return c + 0.5 * float(r @ r) + 0.5 * float(np.sum(lim**2))

    # ------------------------------------------------------------------ normal equations
    def linearize(self, state: State, with_parameters: bool = True,
                  reuse: Linearization | bool | None = None, frames: slice | None = None,
                  parts: str = "all", layout: ColumnLayout | None = None) -> Linearization:
        """Cost and block-arrow normal equations at `state` (weights from the robust loss).
        `reuse`: a Linearization no longer needed, whose arrays are overwritten (saves allocating
        the large B afresh at every iteration); True: the one last handed back by recycle() (the
        solver's last run on this problem), if any.  `frames`: only those frames' blocks (a chunk
        of a long trial, calibrate.solve.chunks): their data and joint-limit terms, no priors
        (prior_normal gives those once).  `parts` (with the parameters): 'all'; 'no_coupling' (B left
        with no columns); 'coupling' (C and g_p zero); 'frames' (A_f and g_z only, the Jacobian kept
        for coupling_times / coupling_transpose): what each pass over a long trial's chunks needs.
        `layout`: the parameter layout at `state.p` (parameter_layout), if already made.

        The per-segment Jacobian blocks are gathered and multiplied frame by frame in compiled
        loops (calibrate.solve.assembly): the time is linear in the frames."""
        sel = ALL if frames is None else frames
        F, nz = self.seen[sel].shape[0], self.model.nz
        if reuse is True:
            reuse = self._work.pop(("lin", not with_parameters), None)
        elif reuse is False:
            reuse = None
        old = reuse.jacobian[:3] if reuse is not None and reuse.jacobian is not None else None  # (d, jz, jp)
        if with_parameters:
            d, jz, jp = self._run("full", state, old, sel)
        else:
            (d, jz), jp = self._run("pose", state, old, sel), None
        cost, w = self._weights(d, sel)
        wrow = np.repeat(w, 3, axis=1)  # (F, 3 nm)
        n = self.n_free if with_parameters else 0
        nb = n if parts in ("all", "coupling") else 0
        A = reuse.A if reuse is not None and reuse.A.shape == (F, nz, nz) else np.empty((F, nz, nz))
        B = reuse.B if reuse is not None and reuse.B.shape == (F, nz, nb) else np.empty((F, nz, nb))
        gz = np.empty((F, nz))
        pl = (layout or self.parameter_layout(state.p)) if with_parameters else None
        if parts == "frames":
            C, gp = assemble(d, wrow, jz, None, self._layout_z, None, A, B, gz, 0)
            C, gp = np.zeros((n, n)), np.zeros(n)
        else:
            C, gp = assemble(d, wrow, jz, jp, self._layout_z, pl, A, B, gz, n, parts=parts)
        a_pat, b_pat = self._block_patterns(pl)
        lim = self.limits(state.Z[sel])
        out = self._limit_active(lim)
        if out.any():
            cost += 0.5 * float(np.sum(lim**2))
            f, d_ = np.nonzero(out)
            k = self._limit_w[d_]
            c = self.layout.frame.angle(d_)
            A[f, c, c] += k * k
            gz[f, c] += k * lim[f, d_]
        Jr = None
        if frames is None:
            r, Jr, G = self.prior_gram(state.p)
            cost += 0.5 * float(r @ r)
            if with_parameters:
                C += G
                gp += Jr.T @ r
        return Linearization(cost, A, B, C, gz, gp, a_pat, b_pat, (d, jz, jp, wrow, pl, Jr, out))

    def parameter_layout(self, p: np.ndarray) -> ColumnLayout:
        """The gather of ∂r/∂p_free from the per-frame Jacobian's nonzeros at parameters `p`
        (calibrate.solve.assembly.parameter_layout through tangent_map(p)): one per state, shared by
        its chunks.  Its indices are built once, on where T may be nonzero at any p
        (ParameterLayout.tangent_pattern): built on T's nonzeros at each p, they were built again at
        every other step of pig_walk (an axis's tangent basis turning from one component to another),
        and with them the Schur complement's row classes."""
        return parameter_layout(self.groups, self.tangent_map(p), self._gather_patterns()[1])

    def _gather_patterns(self) -> tuple:
        """(groups, the gather's pattern, the blocks' patterns (A_f, B_f) on it, Y's nonzeros per frame): built
        once per free set, on where T may be nonzero at any p (parameter_layout)."""
        cached = self.__dict__.get("_pattern_cache")
        if cached is None or cached[0] is not self.groups:
            pattern = parameter_pattern(self.groups, self.layout.tangent_pattern())
            a_pat, b_pat = self.block_patterns(pattern[0])
            cached = (self.groups, pattern, (a_pat, b_pat), int(y_pattern_of(a_pat, b_pat).sum()))
            self._pattern_cache = cached
        return cached

    def y_entries(self) -> int:
        """Nonzeros of a frame's Y = L⁻¹ B_f (calibrate.solve.schur: the elimination keeps only these) over
        the free parameters, at any parameters (the gather's pattern, parameter_layout)."""
        return self._gather_patterns()[3]

    def _block_patterns(self, pl: ColumnLayout | None) -> tuple[np.ndarray, np.ndarray]:
        """block_patterns(pl), kept with the gather's pattern (parameter_layout) when `pl` is built on it."""
        cached = self.__dict__.get("_pattern_cache")
        if pl is not None and cached is not None and cached[0] is self.groups and pl.fcols is cached[1][0].fcols:
            return cached[2]
        return self.block_patterns(pl)

    def coupling_times(self, lin: Linearization, full_step: np.ndarray) -> np.ndarray:
        """B_f dp for every frame of `lin` (F, nz), from its Jacobian (Jz' W² Jp dp) without B_f;
        `full_step`: the step of the full parameters, tangent_map(p) dp."""
        _, jz, jp, wrow, pl = lin.jacobian[:5]
        rows_z, cols_z, rows_p, cols_p = self.jacobian_rows()
        v = (rows_p.T @ (jp * full_step[cols_p]).T).T
        gz = np.empty((v.shape[0], self.model.nz))
        assemble(np.ascontiguousarray(v), wrow, jz, None, self._layout_z, None, lin.A, lin.B, gz, 0,
                 gradient_only=True)
        return gz

    def coupling_transpose(self, lin: Linearization, u: np.ndarray) -> np.ndarray:
        """Σ_f B_f' u_f over the frames of `lin` (u: (F, nz)), from its Jacobian (Jp' W² Jz u) without B_f."""
        _, jz, jp, wrow, pl = lin.jacobian[:5]
        rows_z, cols_z, rows_p, cols_p = self.jacobian_rows()
        v = (rows_z.T @ (jz * u[:, cols_z]).T).T
        gz = np.empty((v.shape[0], self.model.nz))
        _, gp = assemble(np.ascontiguousarray(v), wrow, jz, jp, self._layout_z, pl, lin.A, lin.B, gz, self.n_free,
                         gradient_only=True)
        return gp

    def block_patterns(self, pl) -> tuple[np.ndarray, np.ndarray]:
        """(nz, nz) and (nz, n) bool: which entries of a frame's A_f and B_f can be nonzero (B's
        columns: the free parameters of the parameter layout `pl`; none without it)."""
        nz = self.model.nz
        n = self.n_free if pl is not None else 0
        a_pat = np.eye(nz, dtype=bool)
        b_pat = np.zeros((nz, n), dtype=bool)
        for k, g in enumerate(self.groups):
            a_pat[np.ix_(g.zcols, g.zcols)] = True
            if pl is not None:
                b_pat[np.ix_(g.zcols, pl.fcols[pl.fc_off[k]:pl.fc_off[k + 1]])] = True
        return a_pat, b_pat

    def prior_gradient(self, p: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Jr'r: the priors' Jacobian at `p` times a prior-shaped residual `r` (Problem.gradient's
        prior part, for blocks formed chunk by chunk)."""
        return self.prior(p)[1].T @ r

    def prior_normal(self, p: np.ndarray, with_parameters: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
        """The priors' share of the normal equations at `p`: (cost, Jr'Jr, Jr'r) (empty without the
        parameters), what linearize adds once to the frames' blocks."""
        if not with_parameters:
            r, _ = self.prior(p, jacobian=False)
            return 0.5 * float(r @ r), np.zeros((0, 0)), np.zeros(0)
        r, Jr, G = self.prior_gram(p)
        return 0.5 * float(r @ r), G, Jr.T @ r

    def residual_parts(self, state: State, frames: slice = ALL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The residuals at `state`, unweighted markers (F, 3 n_markers; 0 where not seen), joint
        limits (F, n_dofs) and priors: what the geodesic acceleration differentiates twice.  `frames`:
        a chunk of frames, which `state` holds alone (then the priors' part is empty)."""
        d = self._run("resid", state, frames=frames)[0]
        whole = frames == ALL
        r = self.prior(state.p, jacobian=False)[0] if whole else np.zeros(0)
        return np.where(np.repeat(self.seen[frames], 3, axis=1), d, 0.0), self.limits(state.Z), r

    def gradient(self, lin: Linearization, d: np.ndarray, lim: np.ndarray,
                 r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """J'ρ for residuals ρ = (markers d (F, 3 n_markers) unweighted, limits lim, priors r), with
        the Jacobian J and weights of `lin`: (g_z (F, nz), g_p (n,)); a linearization of some frames
        only (linearize's `frames`) takes their d and lim, and no priors (r: ignored)."""
        _, jz, jp, wrow, pl, Jr, on = lin.jacobian
        F, nz = lin.gz.shape
        n = lin.gp.size
        gz = np.empty((F, nz))
        _, gp = assemble(np.ascontiguousarray(d), wrow, jz, jp, self._layout_z, pl, lin.A, lin.B, gz, n,
                         gradient_only=True)
        if on.any():
            f, k = np.nonzero(on)
            gz[f, self.layout.frame.angle(k)] += self._limit_w[k] * lim[f, k]
        if n and Jr is not None:
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


