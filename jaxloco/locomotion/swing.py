"""Swing-foot trajectories: a cubic B-spline for the height, a quintic for the ground path.

Paper Section V-B: "third degree B-splines, which guarantee acceleration continuity"; the
authors' code drove the foot through a mid-point 0.1 m above the ground.

- Height: 7 control points on the clamped uniform knot vector ``(0,0,0,0, 1/4, 1/2, 3/4,
  1,1,1,1)`` in normalised time ``u = (t - t0) / T``. The first three fix the start height,
  vertical velocity and acceleration, the last three the landing at rest, the middle one
  the height at ``u = 1/2``.
- Ground path (x, y): a quintic from the start position, velocity and acceleration to the
  target at rest at ``t0 + T``: minimum jerk, and *time-consistent*: re-planning it from
  any point of itself to the same target and landing time gives back the same path. That
  is what a swing re-planned every few ticks (Eq. 33-34 after a push) needs. A B-spline
  refitted the same way is not: each refit speeds the foot up, and replans a few ticks
  apart compound it past the target (docs/architecture.md, measured choices).

A swing re-planned mid-air continues from the old one without a jump in position, velocity
or acceleration, except that its height never dips below the lower of its start and
landing heights, nor rises above twice its height (see :func:`make_swing`): there the
vertical velocity and acceleration jump.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from scipy import interpolate


class Motion(NamedTuple):
    """A point of a reference trajectory: position (or orientation), velocity and
    acceleration at one time. Positions ``(3,)`` in m, m/s, m/s^2; a yaw reference
    (:func:`~jaxloco.locomotion.gait.yaw_reference`) holds a ``(4,)`` quaternion, and the
    angular velocity and acceleration ``(3,)`` (rad/s, rad/s^2); a planar one scalars."""

    pos: jax.Array
    """Position (m), or a (4,) quaternion, or a scalar."""
    vel: jax.Array
    """Velocity (m/s or rad/s)."""
    acc: jax.Array
    """Acceleration (m/s^2 or rad/s^2)."""


KNOTS = np.array([0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1, 1], dtype=np.float64)
DEGREE = 3
NUM_POINTS = len(KNOTS) - DEGREE - 1  # 7


def _piecewise_coefficients() -> np.ndarray:
    """``(4, 7, 4)``: on each of the knot vector's four intervals, the 7 basis functions as
    cubics in the offset from the interval's start (highest power first), from SciPy's exact
    B-spline to piecewise-polynomial conversion."""
    spans = np.flatnonzero(np.diff(KNOTS) > 0)  # the four intervals of non-zero length
    table = np.empty((len(spans), NUM_POINTS, DEGREE + 1))
    for i, unit in enumerate(np.eye(NUM_POINTS)):
        pp = interpolate.PPoly.from_spline(interpolate.BSpline(KNOTS, unit, DEGREE))
        table[:, i, :] = pp.c[:, spans].T
    return table


BASIS_COEFFICIENTS = _piecewise_coefficients()
"""``(4, 7, 4)`` the basis functions as cubics per interval (see :func:`basis_derivatives`)."""


def basis_derivatives(u):
    """``(3, 7)``: the 7 cubic basis functions' values and first and second derivatives
    w.r.t. ``u`` at ``u`` in [0, 1] (clipped; ``u = 1`` belongs to the last interval).

    Evaluated as the piecewise cubics of :data:`BASIS_COEFFICIENTS`: a handful of
    operations, where Cox-de Boor's recursion and its derivatives by ``jacfwd`` traced
    thousands of scalar ones into every program that walks."""
    u = jnp.clip(u, 0.0, 1.0)
    spans = BASIS_COEFFICIENTS.shape[0]
    interval = jnp.minimum(jnp.floor(u * spans), spans - 1)
    s = u - interval / spans
    one, zero = jnp.ones_like(s), jnp.zeros_like(s)
    # Rows: d^k/du^k of (s^3, s^2, s, 1), k = 0, 1, 2.
    powers = jnp.stack(
        [
            jnp.stack([s**3, s**2, s, one]),
            jnp.stack([3.0 * s**2, 2.0 * s, one, zero]),
            jnp.stack([6.0 * s, 2.0 * one, zero, zero]),
        ]
    )
    coefficients = jnp.asarray(BASIS_COEFFICIENTS, s.dtype)[interval.astype(jnp.int32)]
    return powers @ coefficients.T


def basis(u):
    """Values of the 7 cubic basis functions at ``u`` in [0, 1] (clipped)."""
    return basis_derivatives(u)[0]


def quintic(p0, v0, a0, p1, v1, a1, duration, t):
    """Quintic from (p0, v0, a0) at 0 to (p1, v1, a1) at ``duration``; held after it.

    Returns position, velocity and acceleration at ``t``.
    """
    T = duration
    tc = jnp.clip(t, 0.0, T)
    c0, c1, c2 = p0, v0, a0 / 2
    d = p1 - (c0 + c1 * T + c2 * T**2)
    e = v1 - (c1 + 2 * c2 * T)
    f = a1 - 2 * c2
    c3 = (10 * d - 4 * e * T + 0.5 * f * T**2) / T**3
    c4 = (-15 * d + 7 * e * T - f * T**2) / T**4
    c5 = (6 * d - 3 * e * T + 0.5 * f * T**2) / T**5
    pos = c0 + c1 * tc + c2 * tc**2 + c3 * tc**3 + c4 * tc**4 + c5 * tc**5
    vel = c1 + 2 * c2 * tc + 3 * c3 * tc**2 + 4 * c4 * tc**3 + 5 * c5 * tc**4
    acc = 2 * c2 + 6 * c3 * tc + 12 * c4 * tc**2 + 20 * c5 * tc**3
    after = t > T
    return pos, jnp.where(after, v1, vel), jnp.where(after, a1, acc)


@struct.dataclass
class SwingSpline:
    """A swing from ``t0`` to ``t0 + duration``: the height's B-spline ``height_points``
    (7,), the ground path's start ``ground_start`` (3, 2: position, velocity,
    acceleration) and the landing point ``target`` (3,)."""

    height_points: jax.Array
    """(7,) the height's B-spline control points (m above the landing point)."""
    ground_start: jax.Array
    """(3, 2) the ground path's start: position, velocity, acceleration (m, m/s, m/s^2)."""
    target: jax.Array
    """(3,) the landing point (m, world)."""
    t0: jax.Array
    """() the swing's start time (s)."""
    duration: jax.Array
    """() the swing's duration (s)."""

    def evaluate(self, t) -> Motion:
        """Position, velocity and acceleration (3,) each at time ``t`` (held after the end)."""
        duration = jnp.maximum(self.duration, 1e-3)
        u = jnp.clip((t - self.t0) / duration, 0.0, 1.0)
        b = basis_derivatives(u)
        inside = (t >= self.t0) & (t <= self.t0 + duration)
        z = b[0] @ self.height_points
        zd = jnp.where(inside, b[1] @ self.height_points / duration, 0.0)
        zdd = jnp.where(inside, b[2] @ self.height_points / duration**2, 0.0)
        zero = jnp.zeros(2, self.target.dtype)
        g = self.ground_start
        xy, xyd, xydd = quintic(
            g[0], g[1], g[2], self.target[:2], zero, zero, duration, t - self.t0
        )
        before = t < self.t0
        xyd = jnp.where(before, 0.0, xyd)
        xydd = jnp.where(before, 0.0, xydd)
        return Motion(jnp.append(xy, z), jnp.append(xyd, zd), jnp.append(xydd, zdd))


def make_swing(start_pos, target, t0, duration, mid_height, start_vel=None, start_acc=None):
    """A swing from ``start_pos`` (moving at ``start_vel``, ``start_acc``: default at rest)
    to ``target`` at rest after ``duration`` s, with height ``mid_height`` (absolute z) at
    half time. The height stays at or above ``floor = min(start z, target z)``, and below
    ``floor + 2 (max(start z, mid_height) - floor)``: where the start's vertical velocity and
    acceleration would take it beyond, they are not kept."""
    start_pos, target = jnp.asarray(start_pos), jnp.asarray(target)
    dtype = start_pos.dtype
    target = target.astype(dtype)
    duration = jnp.maximum(jnp.asarray(duration, dtype), 1e-3)
    zero = jnp.zeros(3, dtype)
    vel = zero if start_vel is None else jnp.asarray(start_vel, dtype)
    acc = zero if start_acc is None else jnp.asarray(start_acc, dtype)
    # At u = 0 only the first three functions (and their derivatives) are non-zero: a lower
    # triangular system gives the first three control points from position, velocity and
    # acceleration. Constants of the trace, from the same code the spline evaluates.
    s = basis_derivatives(jnp.zeros((), dtype))[:, :3].astype(dtype)
    # Height control points: s[0] @ P = z, s[1] @ P = zd T, s[2] @ P = zdd T^2 over P0..P2.
    h0 = start_pos[2]
    h1 = (vel[2] * duration - s[1, 0] * h0) / s[1, 1]
    h2 = (acc[2] * duration**2 - s[2, 0] * h0 - s[2, 1] * h1) / s[2, 2]
    # The curve lies in its control points' convex hull, so clamping them bounds the foot.
    # Below: the lower of its start and landing heights. That binds for a foot moving down
    # fast that must now land later (a replan near touch-down): continuing its vertical
    # velocity and acceleration would drive the reference through the floor, and the WBLC
    # would press the foot there (docs/architecture.md, measured choices). Above: twice the
    # swing's height (the higher of its start and mid heights, over the floor), for a foot
    # still accelerating up after lift-off that must now land later: its acceleration, kept
    # over the longer swing (h2 grows as zdd T^2), took the reference far above the swing
    # after a sideways push. Twice, not once: a plain
    # swing's control points rise above its curve (1.5 times its height from rest).
    # Position stays continuous; zd, zdd jump where a bound binds.
    floor = jnp.minimum(h0, target[2])
    ceiling = floor + 2.0 * (jnp.maximum(h0, mid_height) - floor)
    h1, h2 = (jnp.clip(h, floor, ceiling) for h in (h1, h2))
    mid = basis(jnp.asarray(0.5, dtype)).astype(dtype)
    partial = mid[0] * h0 + mid[1] * h1 + mid[2] * h2 + (mid[4] + mid[5] + mid[6]) * target[2]
    h3 = jnp.maximum((mid_height - partial) / mid[3], floor)
    height = jnp.stack([h0, h1, h2, h3, target[2], target[2], target[2]])
    ground = jnp.stack([start_pos[:2], vel[:2], acc[:2]])
    return SwingSpline(height, ground, target, jnp.asarray(t0, dtype), duration)


def retarget_swing(old: SwingSpline, t, target, duration, mid_height) -> SwingSpline:
    """``old`` re-planned at time ``t`` to land on ``target`` after ``duration`` s,
    continuing from its position, velocity and acceleration."""
    pos, vel, acc = old.evaluate(t)
    return make_swing(pos, target, t, duration, mid_height, vel, acc)
