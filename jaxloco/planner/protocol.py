"""What a step planner provides: the :class:`Planner` protocol.

The gait (:mod:`jaxloco.locomotion.gait`) asks a planner for one thing each step: the action
at the apex state it will reach. Learned planners (``LearnedPlanner``, ``PPOPlanner``),
their combinations (``FallbackPlanner``) and their size-scaled wrappers (``ScaledPlanner``)
all provide it; a hand-written planner only needs these members to drive the walking
controller. Planners are pytrees (weights as leaves) so they can be passed into ``jit``.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import jax

from jaxloco.planner.psp import PSPParams


@runtime_checkable
class Planner(Protocol):
    """A step policy over apex states, with the PSP it plans with."""

    @property
    def psp(self) -> PSPParams:
        """The phase-space planner's parameters: LIPM height, action box, stride bounds."""
        ...

    def policy(self, state: jax.Array) -> jax.Array:
        """The action for one apex state: ``(3,) -> (3,)``, state ``(y_apex, xd_apex,
        yd_apex)`` (m, m/s, m/s), action ``(p_x, xd_apex_next, yd_apex_next)`` (m, m/s,
        m/s); see :func:`~jaxloco.planner.psp.plan_step`."""
        ...

    def mean_action(self, state: jax.Array) -> jax.Array:
        """Actions for apex states ``(..., 3) -> (..., 3)``."""
        ...

    def value(self, state: jax.Array) -> jax.Array:
        """The planner's value of apex states ``(..., 3) -> (...)`` (the paper's walking
        risk, in reward units)."""
        ...
