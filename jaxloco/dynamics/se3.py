"""Small SE(3) utilities for twists ``V = [w; v]`` (angular first, as in the paper, Eq. 22).

Twists here are *spatial*: expressed in world coordinates at the world origin, so that the
twist of a body is the sum of its joints' screw axes times their velocities (Eq. 26 in the
spatial frame) and the time derivative of a screw axis that moves with the preceding links
is ``ad_{V} S`` (the Lie bracket; paper Eq. 29 with ``Ad_{T'} = Ad_T ad_V``).
"""

from __future__ import annotations

import jaxloco.dynamics.quiet_mjx  # noqa: F401  (before brax, whose math imports MJX)

# isort: split
import jax.numpy as jnp
from brax import math as quat_math


def hat(w):
    """``[w]x``: the 3x3 skew matrix of a vector (Eq. 23)."""
    w = jnp.asarray(w)
    z = jnp.zeros_like(w[..., 0])
    return jnp.stack(
        [
            jnp.stack([z, -w[..., 2], w[..., 1]], -1),
            jnp.stack([w[..., 2], z, -w[..., 0]], -1),
            jnp.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def adjoint(rotation, position):
    """``Ad_T`` (6x6) of ``T = (R, p)`` for twists ``[w; v]`` (Eq. 25)."""
    zeros = jnp.zeros_like(rotation)
    top = jnp.concatenate([rotation, zeros], -1)
    bottom = jnp.concatenate([hat(position) @ rotation, rotation], -1)
    return jnp.concatenate([top, bottom], -2)


def ad(twist):
    """``ad_V`` (6x6) of a twist ``[w; v]``: ``[[w]x, 0], [[v]x, [w]x]``."""
    w, v = twist[..., :3], twist[..., 3:]
    wx, vx = hat(w), hat(v)
    zeros = jnp.zeros_like(wx)
    return jnp.concatenate([jnp.concatenate([wx, zeros], -1), jnp.concatenate([vx, wx], -1)], -2)


def ad_apply(twist, screw):
    """``ad_V S`` without forming the matrix: ``[w x s_w; v x s_w + w x s_v]``."""
    w, v = twist[..., :3], twist[..., 3:]
    sw, sv = screw[..., :3], screw[..., 3:]
    return jnp.concatenate([jnp.cross(w, sw), jnp.cross(v, sw) + jnp.cross(w, sv)], -1)


def point_velocity(twist, point):
    """Linear velocity of a point moving with a body of spatial twist ``[w; v]``."""
    return twist[..., 3:] + jnp.cross(twist[..., :3], point)


def rotation_error(q_desired, q):
    """World-frame rotation vector ``log(q_d q^-1)`` (3,), quaternions ``(w, x, y, z)``.

    The orientation tasks' error: the angular velocity that would turn ``q`` into
    ``q_d`` in unit time, about world axes (matching the angular rows of world-frame
    Jacobians). The shorter way round is taken; the formula is smooth at zero error (its
    gradient too), where ``2 atan2(|v|, w) / |v| -> 2 / w``.
    """
    e = quat_math.quat_mul(q_desired, quat_math.quat_inv(q))
    e = jnp.where(e[0] < 0, -e, e)
    w, v = e[0], e[1:]
    s2 = v @ v
    small = s2 < 1e-12
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    factor = jnp.where(small, 2.0 / w * (1.0 - s2 / (3.0 * w * w)), 2.0 * jnp.arctan2(s, w) / s)
    return factor * v


def yaw_quat(yaw):
    """Quaternion ``(w, x, y, z)`` of a rotation by ``yaw`` about the world z axis."""
    yaw = jnp.asarray(yaw)
    zero = jnp.zeros_like(yaw)
    return jnp.stack([jnp.cos(yaw / 2), zero, zero, jnp.sin(yaw / 2)], axis=-1)


def quat_slerp(q0, q1, s):
    """Spherical linear interpolation from ``q0`` (s = 0) to ``q1`` (s = 1), shorter way.

    Falls back to normalised linear interpolation when the two are within 1e-6 rad
    (where slerp's ``sin`` ratio is 0/0), so it is finite everywhere.
    """
    dot = jnp.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = jnp.where(dot < 0, -q1, q1)
    dot = jnp.abs(dot)
    angle = jnp.arccos(jnp.clip(dot, -1.0, 1.0))
    sin = jnp.sin(angle)
    near = sin < 1e-6
    sin_safe = jnp.where(near, 1.0, sin)
    a = jnp.where(near, 1.0 - s, jnp.sin((1.0 - s) * angle) / sin_safe)
    b = jnp.where(near, s, jnp.sin(s * angle) / sin_safe)
    q = a * q0 + b * q1
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)
