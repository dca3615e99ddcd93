"""What the walking controller reports every tick: :class:`WalkingLog`.

One tick's log holds scalars and small vectors; the simulators stack it over time (a leading
axis of ticks, and of robots when batched), so every field's shape below gains those axes.
Sweeps fold it into their outcomes (:mod:`jaxloco.sweep.outcome`), the experiments plot it,
tuning builds its costs from it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco.control.segments import Segments
from jaxloco.control.wblc import WBLCOutput
from jaxloco.locomotion.gait import GaitReferences, GaitState


@struct.dataclass
class WalkingLog:
    """One control tick of the walking controller (world frame, SI units)."""

    com: jax.Array
    """(3,) centre of mass position (m)."""
    com_vel: jax.Array
    """(3,) centre of mass velocity (m/s)."""
    com_ref: jax.Array
    """(3,) the gait's CoM position reference (m): the LIPM about the stance foot."""
    com_error: jax.Array
    """() Eq. 33's error, the replanning criterion: the norm of the horizontal CoM
    position error (m) stacked with half its velocity error (m/s)."""
    contact: jax.Array
    """(2,) contact weights of (left, right) in [0, 1]."""
    stance: jax.Array
    """() int32, the stance foot: 0 left, 1 right."""
    phase: jax.Array
    """() int32, the gait phase: ``gait.START`` (0) or ``gait.WALK`` (1)."""
    step: jax.Array
    """() int32, steps begun so far (the first lift-off begins step 1)."""
    target: jax.Array
    """(3,) footstep the swing foot is heading to (m)."""
    replans: jax.Array
    """() int32, re-plans so far (Section IV-C's replanning)."""
    step_duration: jax.Array
    """() planned time from the step's start to its touch-down (s)."""
    apex: jax.Array
    """(3,) the last plan's apex state ``(y_apex, xd_apex, yd_apex)`` in the stance frame
    (m, m/s, m/s; see :func:`~jaxloco.planner.psp.plan_step`)."""
    action: jax.Array
    """(3,) the last plan's action ``(p_x, xd_apex_next, yd_apex_next)`` (m, m/s, m/s)."""
    reason: jax.Array
    """() int32, the last plan's :class:`~jaxloco.planner.psp.Reason` bit flags."""
    failed_plans: jax.Array
    """() int32, plans so far that had no solution and fell back to a capture step."""
    heading: jax.Array
    """() heading of the current step (rad, about world z)."""
    feet: jax.Array
    """(2, 3) contact-frame positions of (left, right) feet (m)."""
    swing_ref: jax.Array
    """(3,) the swing foot's position reference (m)."""
    torque_norm: jax.Array
    """() Euclidean norm of the controller's joint torques (N m)."""
    relaxed: jax.Array
    """() bool, the force QP relaxed its friction cone this tick."""
    over_limit: jax.Array
    """() bool, some joint torque exceeded its effort limit this tick."""
    limited: jax.Array
    """() bool, the controller's limit stage changed the torques this tick to keep them
    within their limits (``WBLCConfig.whole_body_limits``)."""
    relaxation: Segments
    """Per task (by name, one value each), the norm of the acceleration change the limit
    stage made it give way (m/s^2 or rad/s^2; 0 when the stage did not act)."""

    @classmethod
    def of(
        cls,
        com: jax.Array,
        com_vel: jax.Array,
        feet: jax.Array,
        gait: GaitState,
        refs: GaitReferences,
        out: WBLCOutput,
    ) -> WalkingLog:
        """The log of a tick from the measured CoM state and feet, the gait state after
        the tick, its references and the WBLC's output."""
        return cls(
            com=com,
            com_vel=com_vel,
            com_ref=refs.com.pos,
            com_error=refs.com_error,
            contact=refs.contact,
            stance=gait.stance,
            phase=gait.phase,
            step=gait.step,
            target=gait.target,
            replans=gait.replans,
            step_duration=gait.step_duration,
            apex=gait.last_apex,
            action=gait.last_action,
            reason=gait.last_reason,
            failed_plans=gait.failed_plans,
            heading=gait.heading,
            feet=feet,
            swing_ref=refs.swing.pos,
            torque_norm=jnp.linalg.norm(out.torques),
            relaxed=out.diagnostics.qp_relaxed,
            over_limit=jnp.any(out.diagnostics.torque_over_limit),
            limited=out.diagnostics.torque_limit.active,
            relaxation=Segments.stack(
                {
                    name: jnp.linalg.norm(change, keepdims=True)
                    for name, change in out.diagnostics.task_relaxation.as_dict().items()
                }
            ),
        )
