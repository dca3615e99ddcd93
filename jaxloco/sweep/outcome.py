"""What a sweep keeps of each pushed run: a small accumulator updated every tick.

Both physics backends update the same :class:`Outcome` from the walking controller's
per-tick log, inside their jitted step, so a run of thousands of ticks leaves a handful of
numbers per robot instead of a trajectory.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxloco.locomotion.walking_log import WalkingLog

# Columns a sweep writes per push (besides the push's own columns).
FIELDS = (
    "recovered",
    "fell",
    "fall_time",
    "steps_after",
    "replans",
    "failed_plans",
    "max_com_error",
    "max_com_offset",
    "peak_torque_norm",
    "relaxed_ticks",
    "over_limit_ticks",
)


@struct.dataclass
class Outcome:
    fell: jax.Array
    """() bool, the base fell below the fall height within the horizon."""
    fall_time: jax.Array
    """Time (s) of the fall relative to the push's start; inf while standing."""
    step0: jax.Array
    """() int, steps begun when the push started."""
    step: jax.Array
    """() int, steps begun at the end (or the fall)."""
    replans0: jax.Array
    """() int, replans when the push started."""
    replans: jax.Array
    """() int, replans at the end."""
    failed0: jax.Array
    """() int, failed plans when the push started."""
    failed: jax.Array
    """() int, failed plans at the end."""
    max_com_error: jax.Array
    """Eq. 33's error (horizontal CoM state against the planned one), max over the run."""
    max_com_offset: jax.Array
    """Horizontal distance of the CoM from its reference (m), max over the run."""
    peak_torque_norm: jax.Array
    """() largest norm of the commanded torques over the run (N m)."""
    relaxed_ticks: jax.Array
    """Ticks on which the force QP relaxed the friction cone (mu 0.65 -> 1.75)."""
    over_limit_ticks: jax.Array
    """Ticks on which some torque exceeded the model's limit."""


def init_outcome(controller_state) -> Outcome:
    """The accumulator at the push's start, from the walking controller's state."""
    g = controller_state.gait
    dtype = g.step_start.dtype
    zero_i = jnp.zeros((), jnp.int32)
    zero = jnp.zeros((), dtype)
    return Outcome(
        fell=jnp.asarray(False),
        fall_time=jnp.asarray(jnp.inf, dtype),
        step0=g.step,
        step=g.step,
        replans0=g.replans,
        replans=g.replans,
        failed0=g.failed_plans,
        failed=g.failed_plans,
        max_com_error=zero,
        max_com_offset=zero,
        peak_torque_norm=zero,
        relaxed_ticks=zero_i,
        over_limit_ticks=zero_i,
    )


def update_outcome(o: Outcome, log: WalkingLog, alive) -> Outcome:
    """Fold one tick's walking ``log`` in (nothing changes once ``alive`` is False)."""
    offset = jnp.linalg.norm(log.com[:2] - log.com_ref[:2])

    def grow(old, new):
        return jnp.where(alive, new, old)

    return o.replace(
        step=grow(o.step, log.step),
        replans=grow(o.replans, log.replans),
        failed=grow(o.failed, log.failed_plans),
        max_com_error=grow(o.max_com_error, jnp.maximum(o.max_com_error, log.com_error)),
        max_com_offset=grow(o.max_com_offset, jnp.maximum(o.max_com_offset, offset)),
        peak_torque_norm=grow(o.peak_torque_norm, jnp.maximum(o.peak_torque_norm, log.torque_norm)),
        relaxed_ticks=o.relaxed_ticks + (alive & log.relaxed).astype(jnp.int32),
        over_limit_ticks=o.over_limit_ticks + (alive & log.over_limit).astype(jnp.int32),
    )


def mark_fallen(o: Outcome, fell_now, elapsed) -> Outcome:
    """Record a fall detected at ``elapsed`` s after the push's start."""
    new = fell_now & ~o.fell
    return o.replace(fell=o.fell | fell_now, fall_time=jnp.where(new, elapsed, o.fall_time))


def finalize(o: Outcome, steps_after: int) -> dict:
    """Per-push columns (numpy) from a batch of accumulators."""
    o = jax.tree.map(np.asarray, o)
    taken = o.step - o.step0
    return {
        "recovered": (~o.fell) & (taken >= steps_after),
        "fell": o.fell,
        "fall_time": o.fall_time.astype(float),
        "steps_after": taken.astype(int),
        "replans": (o.replans - o.replans0).astype(int),
        "failed_plans": (o.failed - o.failed0).astype(int),
        "max_com_error": o.max_com_error.astype(float),
        "max_com_offset": o.max_com_offset.astype(float),
        "peak_torque_norm": o.peak_torque_norm.astype(float),
        "relaxed_ticks": o.relaxed_ticks.astype(int),
        "over_limit_ticks": o.over_limit_ticks.astype(int),
    }
