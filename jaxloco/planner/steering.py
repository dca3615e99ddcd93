"""Steering: local step frames, their mirroring, and re-projection to a new heading.

Paper: Fig. 3b and Fig. 11. Each step's local frame has its origin at the stance foot and
its x axis along that step's walking direction (heading ``psi``). Its y axis is mirrored
each step: ``lateral_sign = +1`` when local +y is world-left of the heading (stance on the
right foot, next foot to the left), ``-1`` otherwise. To turn, the next frame is rotated by
the heading change and the CoM state is projected into it; the planner then continues from
that (generally non-apex) state.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np


def frame_matrix(heading, lateral_sign):
    """``(..., 2, 2)`` matrix mapping local-frame vectors to world vectors.

    Columns: the local x axis ``(cos psi, sin psi)`` and the local y axis
    ``lateral_sign * (-sin psi, cos psi)``.
    """
    heading, lateral_sign = jnp.asarray(heading), jnp.asarray(lateral_sign)
    c, s = jnp.cos(heading), jnp.sin(heading)
    col_x = jnp.stack([c, s], axis=-1)
    col_y = lateral_sign[..., None] * jnp.stack([-s, c], axis=-1)
    return jnp.stack([col_x, col_y], axis=-1)


def local_to_world(vec, heading, lateral_sign):
    """Rotate local ``(..., 2)`` vectors into the world frame."""
    return jnp.einsum("...ij,...j->...i", frame_matrix(heading, lateral_sign), vec)


def world_to_local(vec, heading, lateral_sign):
    """Rotate world ``(..., 2)`` vectors into a local frame (the inverse of local_to_world)."""
    return jnp.einsum("...ji,...j->...i", frame_matrix(heading, lateral_sign), vec)


def reproject_com_state(com_state, heading, lateral_sign, new_heading, new_lateral_sign):
    """Express a CoM state ``(..., 4) = (x, xd, y, yd)`` in another frame with the same origin.

    Positions and velocities are both rotated (the frames do not move relative to each
    other, so no transport term appears).
    """
    pos = jnp.stack([com_state[..., 0], com_state[..., 2]], axis=-1)
    vel = jnp.stack([com_state[..., 1], com_state[..., 3]], axis=-1)
    pos_w = local_to_world(pos, heading, lateral_sign)
    vel_w = local_to_world(vel, heading, lateral_sign)
    pos_n = world_to_local(pos_w, new_heading, new_lateral_sign)
    vel_n = world_to_local(vel_w, new_heading, new_lateral_sign)
    return jnp.stack([pos_n[..., 0], vel_n[..., 0], pos_n[..., 1], vel_n[..., 1]], axis=-1)


def turn_local_frame(com_state, lateral_sign, cos_turn, sin_turn):
    """Re-project a CoM state into the frame turned by ``turn`` about the same origin.

    The special case of :func:`reproject_com_state` with the same lateral sign on both
    sides: with ``D = diag(1, sigma)``, ``D R(-turn) D = R(-sigma turn)``, so the new local
    coordinates are the old ones rotated by ``-sigma * turn``. Takes the turn's cosine and
    sine (precomputed, so a scan over steps has no trigonometry in its body).
    """
    s = lateral_sign * sin_turn
    x, xd, y, yd = (com_state[..., i] for i in range(4))
    return jnp.stack(
        [
            cos_turn * x + s * y,
            cos_turn * xd + s * yd,
            cos_turn * y - s * x,
            cos_turn * yd - s * xd,
        ],
        axis=-1,
    )


def turn_schedule(segments: Sequence[tuple[int, float]]) -> np.ndarray:
    """Per-step heading changes (radians) from ``[(num_steps, degrees_per_step), ...]``.

    Fig. 11 of the paper is ``turn_schedule([(12, 18.8), (5, 0.0), (12, -18.8)])``.
    """
    turns = []
    for i, (count, degrees) in enumerate(segments):
        if int(count) != count or count < 0:
            raise ValueError(
                f"turn_schedule segment {i}: num_steps must be an int >= 0, got {count!r}"
            )
        if not np.isfinite(degrees) or abs(degrees) >= 90.0:
            raise ValueError(
                f"turn_schedule segment {i}: degrees_per_step must be in (-90, 90), got {degrees!r}"
            )
        turns.extend([np.deg2rad(degrees)] * int(count))
    return np.asarray(turns, dtype=np.float64)
