"""The plain data of the calibration problem: a State (every frame's coordinates and the parameters),
a Linearization (the frame blocks of the normal equations), a segment's group of Jacobian entries."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
class FrameGroup:
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


FrameTurn = tuple[int, str, np.ndarray, np.ndarray]  # (segment, gauge kind, rotation G, shift t) of a frame turn
