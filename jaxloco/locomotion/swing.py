"""Swing-foot trajectories: clamped cubic B-splines (acceleration continuous).

Paper Section V-B: "third degree B-splines, which guarantee acceleration continuity"; the
authors' code drove the foot through a mid-point 0.1 m above the ground
(``shared/reference/paper-details.md``).

A swing is 7 control points on the clamped uniform knot vector ``(0,0,0,0, 1/4, 1/2, 3/4,
1,1,1,1)`` in normalised time ``u = (t - t0) / T``. The first three control points fix the
start position, velocity and acceleration (so a swing re-planned mid-air continues from
the old one without a jump in position, velocity or acceleration); the last three fix the
end at rest on the target; the middle one sets the height at ``u = 1/2``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

KNOTS = np.array([0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1, 1], dtype=np.float64)
DEGREE = 3
NUM_POINTS = len(KNOTS) - DEGREE - 1  # 7


def basis(u):
    """Values of the 7 cubic basis functions at ``u`` in [0, 1] (Cox-de Boor)."""
    u = jnp.clip(u, 0.0, 1.0)
    k = KNOTS
    # Degree 0: the half-open interval holding u; u = 1 belongs to the last real interval.
    last = len(k) - DEGREE - 2
    n = [
        jnp.where(
            (u >= k[i]) & ((u < k[i + 1]) | ((i == last) & (u >= k[i + 1]))) & (k[i + 1] > k[i]),
            1.0,
            0.0,
        )
        for i in range(len(k) - 1)
    ]
    for p in range(1, DEGREE + 1):
        nxt = []
        for i in range(len(k) - 1 - p):
            left = 0.0 if k[i + p] == k[i] else (u - k[i]) / (k[i + p] - k[i]) * n[i]
            den = k[i + p + 1] - k[i + 1]
            right = 0.0 if den == 0 else (k[i + p + 1] - u) / den * n[i + 1]
            nxt.append(left + right)
        n = nxt
    return jnp.stack(n)


def basis_derivatives(u):
    """``(3, 7)``: basis values and their first and second derivatives w.r.t. ``u``."""
    d1 = jax.jacfwd(basis)
    return jnp.stack([basis(u), d1(u), jax.jacfwd(d1)(u)])


# At u = 0 only the first three functions (and their derivatives) are non-zero: a lower
# triangular system gives the first three control points from position, velocity and
# acceleration. Computed once, in float64, with the same code the spline evaluates.
_START = np.asarray(basis_derivatives(0.0), np.float64)[:, :3]
_MID = np.asarray(basis(0.5), np.float64)


@struct.dataclass
class SwingSpline:
    """A swing trajectory: ``control_points`` (7, 3), start time ``t0`` and ``duration``."""

    control_points: jax.Array
    t0: jax.Array
    duration: jax.Array

    def evaluate(self, t):
        """Position, velocity and acceleration (3,) each at time ``t`` (held after the end)."""
        duration = jnp.maximum(self.duration, 1e-3)
        u = jnp.clip((t - self.t0) / duration, 0.0, 1.0)
        b = basis_derivatives(u)
        inside = (t >= self.t0) & (t <= self.t0 + duration)
        pos = b[0] @ self.control_points
        vel = jnp.where(inside, b[1] @ self.control_points / duration, 0.0)
        acc = jnp.where(inside, b[2] @ self.control_points / duration**2, 0.0)
        return pos, vel, acc

    @property
    def target(self):
        return self.control_points[-1]


def make_swing(start_pos, target, t0, duration, mid_height, start_vel=None, start_acc=None):
    """A swing from ``start_pos`` (moving at ``start_vel``, ``start_acc``: default at rest)
    to ``target`` at rest, with height ``mid_height`` (absolute z) at half time.

    The horizontal path's middle control point sits halfway between its neighbours.
    """
    start_pos, target = jnp.asarray(start_pos), jnp.asarray(target)
    dtype = start_pos.dtype
    duration = jnp.maximum(jnp.asarray(duration, dtype), 1e-3)
    zero = jnp.zeros(3, dtype)
    vel = zero if start_vel is None else jnp.asarray(start_vel, dtype) * duration
    acc = zero if start_acc is None else jnp.asarray(start_acc, dtype) * duration**2
    s = jnp.asarray(_START, dtype)
    # Rows: s[0] @ P = pos (P0 = pos), s[1] @ P = vel, s[2] @ P = acc, over P0..P2.
    p0 = start_pos
    p1 = (vel - s[1, 0] * p0) / s[1, 1]
    p2 = (acc - s[2, 0] * p0 - s[2, 1] * p1) / s[2, 2]
    p4 = p5 = p6 = target
    p3_xy = 0.5 * (p2[:2] + p4[:2])
    mid = jnp.asarray(_MID, dtype)
    partial = mid[0] * p0 + mid[1] * p1 + mid[2] * p2 + (mid[4] + mid[5] + mid[6]) * target
    p3_z = (mid_height - partial[2]) / mid[3]
    p3 = jnp.concatenate([p3_xy, p3_z[None]])
    points = jnp.stack([p0, p1, p2, p3, p4, p5, p6])
    return SwingSpline(points, jnp.asarray(t0, dtype), duration)
