"""The paper's error model (METHOD.md Eq. 1–4): an ``E`` per joint plus base and tool.

Frames are numbered ``0`` = base (``E0``), ``1 … nj`` = joints, ``nj + 1`` = tool (``Etool``).
Each frame has six error motions, in this order::

    MOTIONS = ("dx", "dy", "dz", "ex", "ey", "ez")   # δx δy δz (m), εx εy εz (rad)

and each motion of a joint frame is a Chebyshev series in the joint reading mapped to
``u ∈ [-1, 1]`` over ``[q_lo, q_hi]`` (Eq. 2–3) with its own order.  Base and tool are
constant (order 0).  Order ``-1`` means the motion is not in the model.

The whole loop (Eq. 4) maps the robot's joints to the measured target pose in the
instrument frame::

    T_instr_target = T_instr_base0 · E0 · Π_i [Rz(θ_i) · E_i(θ_i) · C_i] · T_flange_target0 · Etool

``T_instr_base0`` and ``T_flange_target0`` are the initial estimates of base and tool (the
instrument may be metres away and rotated); ``E0`` and ``Etool`` are the small corrections
the fit identifies.  See :mod:`quickhealth.identify.robot` for where ``E_i`` sits and
:func:`quickhealth.identify.linearize.loop_pose` for the one implementation of the loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F = NDArray[np.float64]
MOTIONS: tuple[str, ...] = ("dx", "dy", "dz", "ex", "ey", "ez")
MOTION_WORDS: dict[str, str] = {
    "dx": "radial error motion along x",
    "dy": "radial error motion along y",
    "dz": "axial error motion",
    "ex": "tilt about x",
    "ey": "tilt about y",
    "ez": "angular positioning error",
}


def chebyshev_u(q: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> F:
    """Map joint angles to ``u = 2 (q − lo) / (hi − lo) − 1`` (Eq. 2)."""
    q = np.asarray(q, dtype=float)
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    return 2.0 * (q - lo) / (hi - lo) - 1.0


def chebyshev_basis(u: ArrayLike, order: int) -> F:
    """Chebyshev polynomials ``c0 … c_order`` at ``u``: shape ``(*u.shape, order + 1)`` (Eq. 3)."""
    u = np.asarray(u, dtype=float)
    out = np.empty((*u.shape, max(order, 0) + 1))
    out[..., 0] = 1.0
    if order >= 1:
        out[..., 1] = u
    for k in range(2, order + 1):
        out[..., k] = 2.0 * u * out[..., k - 1] - out[..., k - 2]
    return out[..., : order + 1] if order >= 0 else out[..., :0]


@dataclass(frozen=True, eq=False)
class ErrorModelSpec:
    """Which Chebyshev orders the model has, and the joint ranges they are mapped over.

    Attributes
    ----------
    orders : ndarray of int, shape (nj + 2, 6)
        Order of each frame's six motions; ``-1`` = absent.  Row 0 is the base, rows
        ``1 … nj`` the joints, row ``nj + 1`` the tool; base and tool rows are 0 or -1.
    q_lo, q_hi : ndarray, shape (nj,), rad
        Range of each joint that ``u ∈ [-1, 1]`` spans.
    """

    orders: NDArray[np.int64]
    q_lo: F
    q_hi: F

    def __post_init__(self) -> None:
        o = np.asarray(self.orders, dtype=np.int64)
        object.__setattr__(self, "orders", o)
        object.__setattr__(self, "q_lo", np.asarray(self.q_lo, dtype=float))
        object.__setattr__(self, "q_hi", np.asarray(self.q_hi, dtype=float))
        if o.ndim != 2 or o.shape[1] != 6:
            raise ValueError(f"orders must have shape (n_joints + 2, 6), got {o.shape}")
        if np.any(o[[0, -1]] > 0):
            raise ValueError("base and tool error transforms are constant: orders 0 or -1")
        if np.any(self.q_hi <= self.q_lo):
            raise ValueError("every joint range needs q_hi > q_lo")

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return int(self.orders.shape[0] - 2)

    @property
    def n_params(self) -> int:
        """Number of Chebyshev coefficients."""
        return int(np.sum(self.orders + 1))

    def frame_name(self, f: int) -> str:
        """``base``, ``j1`` … ``jN`` or ``tool``."""
        if f == 0:
            return "base"
        if f == self.n_joints + 1:
            return "tool"
        return f"j{f}"

    def index(self) -> NDArray[np.int64]:
        """Parameter layout: one row ``(frame, motion, k)`` per coefficient, shape (n_params, 3)."""
        rows = [
            (f, m, k)
            for f in range(self.orders.shape[0])
            for m in range(6)
            for k in range(self.orders[f, m] + 1)
        ]
        return np.array(rows, dtype=np.int64).reshape(-1, 3)

    def labels(self) -> list[str]:
        """Human-readable coefficient names, e.g. ``j1.ez.c3``, ``base.dx.c0``."""
        return [f"{self.frame_name(f)}.{MOTIONS[m]}.c{k}" for f, m, k in self.index()]

    def with_orders(self, orders: ArrayLike) -> ErrorModelSpec:
        """The same ranges with other orders."""
        return ErrorModelSpec(np.asarray(orders, dtype=np.int64), self.q_lo, self.q_hi)

    @classmethod
    def uniform(
        cls,
        n_joints: int,
        order: int,
        q_lo: ArrayLike,
        q_hi: ArrayLike,
        base: bool = True,
        tool: bool = True,
    ) -> ErrorModelSpec:
        """Every joint motion at ``order``; base and tool constant (or absent)."""
        o = np.full((n_joints + 2, 6), order, dtype=np.int64)
        o[0] = 0 if base else -1
        o[-1] = 0 if tool else -1
        return cls(o, np.asarray(q_lo, float), np.asarray(q_hi, float))


def split_coefficients(spec: ErrorModelSpec, coeffs: ArrayLike) -> list[list[F]]:
    """Coefficient vector → ``[frame][motion] -> array of order+1 coefficients``."""
    c = np.asarray(coeffs, dtype=float)
    if c.shape != (spec.n_params,):
        raise ValueError(f"expected {spec.n_params} coefficients, got {c.shape}")
    out: list[list[F]] = []
    pos = 0
    for f in range(spec.orders.shape[0]):
        row = []
        for m in range(6):
            k = int(spec.orders[f, m]) + 1
            row.append(c[pos : pos + k])
            pos += k
        out.append(row)
    return out


def joint_error_motions(spec: ErrorModelSpec, coeffs: ArrayLike, q: ArrayLike) -> F:
    """The six error motions of every joint at the readings ``q``.

    Parameters
    ----------
    q : array, shape (n, nj), rad

    Returns
    -------
    ndarray, shape (n, nj, 6): δx δy δz (m), εx εy εz (rad).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    parts = split_coefficients(spec, coeffs)
    u = chebyshev_u(q, spec.q_lo, spec.q_hi)
    out = np.zeros((q.shape[0], spec.n_joints, 6))
    max_order = int(spec.orders[1:-1].max(initial=-1))
    if max_order < 0:
        return out
    B = chebyshev_basis(u, max_order)  # (n, nj, K)
    for j in range(spec.n_joints):
        for m in range(6):
            c = parts[j + 1][m]
            if c.size:
                out[:, j, m] = B[:, j, : c.size] @ c
    return out


def constant_motions(spec: ErrorModelSpec, coeffs: ArrayLike, frame: int) -> F:
    """The six constant motions of the base (``frame=0``) or tool (``frame=-1``), shape (6,)."""
    parts = split_coefficients(spec, coeffs)[frame]
    return np.array([p[0] if p.size else 0.0 for p in parts])
