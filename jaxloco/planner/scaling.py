"""Froude scaling: the phase-space planner of one robot size serves every size.

The LIPM ``xdd = g / h (x - p)`` keeps its form when lengths are multiplied by ``L`` and
times by ``sqrt(L)`` (so velocities by ``sqrt(L)``): a robot whose walking CoM height is
``L`` times another's walks the same gait, step for step, in scaled units. A step policy
learned at one height therefore serves any other through :class:`FroudeScale`: apex states
are divided by the state units before the policy sees them, and its actions multiplied by
the action units. Eq. 2's action box and Eq. 4's safe set scale the same way
(:func:`scale_psp`), so a plan that is safe at one size is safe at the other.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from jaxloco.planner.psp import PSPParams

_LENGTHS = (
    "h",
    "y_apex_nominal",
    "p_y_nominal",
    "p_y_min",
    "p_y_max",
    "stride_min",
    "stride_max",
    "p_x_min",
    "p_x_max",
)
_VELOCITIES = (
    "xd_apex_nominal",
    "xd_apex_next_min",
    "xd_apex_next_max",
    "yd_apex_next_min",
    "yd_apex_next_max",
)
_TIMES = ("t_switch_min", "t_apex_min")
# The reward (Eq. 3) is in squared velocities: its lateral-step weight has units 1/s^2 (it
# multiplies a squared length), and the whole reward, the terminal one too, scales by L.
_REWARDS = ("terminal_reward",)
_PER_TIME_SQUARED = ("reward_weight_p_y",)


@dataclasses.dataclass(frozen=True)
class FroudeScale:
    """Units of one robot size relative to another: lengths ``length``, times and
    velocities ``sqrt(length)``."""

    length: float = 1.0
    """Length ratio (e.g. the walking CoM heights' ratio), > 0."""

    def __post_init__(self):
        if not (isinstance(self.length, (int, float)) and math.isfinite(self.length)):
            raise ValueError(f"FroudeScale.length must be a finite number; got {self.length!r}")
        if self.length <= 0:
            raise ValueError(f"FroudeScale.length must be > 0; got {self.length}")

    @property
    def time(self) -> float:
        return math.sqrt(self.length)

    @property
    def velocity(self) -> float:
        return math.sqrt(self.length)

    @property
    def state_units(self) -> tuple[float, float, float]:
        """Units of an apex state ``(y, xd, yd)``."""
        return (self.length, self.velocity, self.velocity)

    @property
    def action_units(self) -> tuple[float, float, float]:
        """Units of an action ``(p_x, xd_apex, yd_apex)``."""
        return (self.length, self.velocity, self.velocity)

    def to_reference(self, state):
        """An apex state ``(..., 3)`` in the reference size's units."""
        return state / jnp.asarray(self.state_units, jnp.asarray(state).dtype)

    def from_reference(self, action):
        """An action ``(..., 3)`` of the reference size, in this size's units."""
        return action * jnp.asarray(self.action_units, jnp.asarray(action).dtype)


def scale_psp(psp: PSPParams, scale: FroudeScale) -> PSPParams:
    """``psp`` for a robot ``scale`` times the size it was made for (``g`` unchanged)."""
    factors = {
        **dict.fromkeys(_LENGTHS, scale.length),
        **dict.fromkeys(_VELOCITIES, scale.velocity),
        **dict.fromkeys(_TIMES, scale.time),
        **dict.fromkeys(_REWARDS, scale.length),
        **dict.fromkeys(_PER_TIME_SQUARED, 1.0 / scale.length),
    }
    return dataclasses.replace(psp, **{name: getattr(psp, name) * f for name, f in factors.items()})
