"""A step policy learned at one robot size, serving a robot of another size (Froude
scaling, :mod:`jaxloco.planner.scaling`): :class:`ScaledPlanner`."""

from __future__ import annotations

import dataclasses

from flax import struct

from jaxloco.learning.evaluation import over_states
from jaxloco.planner import FroudeScale, PSPParams, scale_psp


@struct.dataclass
class ScaledPlanner:
    """``planner`` (learned at the reference size) for a robot ``scale`` times that size.

    Apex states are taken to the reference's units before ``planner`` sees them and its
    actions brought back; ``psp`` is the planner's parameters at this size. The planners'
    interface (``policy``, ``mean_action``, ``value``, ``psp``); a pytree."""

    planner: object
    """The planner at the reference size (``LearnedPlanner``, ``FallbackPlanner``...)."""
    scale: FroudeScale = struct.field(pytree_node=False)

    @property
    def psp(self) -> PSPParams:
        return scale_psp(self.planner.psp, self.scale)

    def policy(self, state):
        """The policy for one apex state ``(3,) -> (3,)``, in this size's units."""
        return self.scale.from_reference(self.planner.policy(self.scale.to_reference(state)))

    def mean_action(self, state):
        return over_states(self.policy, state)

    def value(self, state):
        """The reference planner's value at the state in its units (reward units of the
        reference size)."""
        return self.planner.value(self.scale.to_reference(state))


def planner_at_height(planner, h: float):
    """``planner`` planning with LIPM height ``h`` (m) at its own size: its ``psp.h`` (and,
    for a :class:`ScaledPlanner`, its reference planner's, in reference units) replaced."""
    if isinstance(planner, ScaledPlanner):
        inner = planner_at_height(planner.planner, h / planner.scale.length)
        return planner.replace(planner=inner)
    return planner.replace(psp=dataclasses.replace(planner.psp, h=h))
