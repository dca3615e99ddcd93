"""A step policy with a fallback: one policy where a look-ahead shows it walks on, another
where it does not.

:class:`FallbackPlanner` takes the *primary* policy's action at an apex state when the
primary, rolled ``steps`` steps through the planner from that state, stays safe (Eq. 4 and
the stride bounds at every step); elsewhere it takes the *fallback* policy's action (with
``strict``, only where the fallback's own look-ahead is safe). The
look-ahead is the same analytic PSP the policies were trained on, so it costs ``steps``
planner steps of each policy per call (unrolled: a scanned one made the batched walking
tick several times slower), and it runs in the planner's current :class:`PSPParams` (on the
robot, the walking height that ``make_walking_controller`` sets).

Why: a policy that walks the full robot well (the walking controller's gains and gait were
tuned with it) can keep every action it takes where it walks on, while a policy with a
larger survival basin takes over the states it fails from. The shipped default is Algorithm
1's policy with the refined one as its fallback (``docs/learning.md``). It is not in the
paper.

A checkpoint is a folder holding ``fallback.json``: the look-ahead's ``steps`` and the
paths of the two checkpoints (relative to the folder, or absolute), which
:func:`~jaxloco.learning.loading.load_planner` loads.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
from flax import struct

from jaxloco.learning.checkpoint import FALLBACK_FILE
from jaxloco.learning.evaluation import over_states
from jaxloco.planner import Planner, PSPParams, plan_steps

FORMAT_VERSION = 1


@struct.dataclass
class FallbackPlanner:
    """The primary policy's action where its ``steps``-step look-ahead is safe, else the
    fallback's. :class:`~jaxloco.learning.LearnedPlanner`'s interface (``policy``,
    ``mean_action``, ``value``, ``psp``); a pytree, so it can be passed into ``jit``."""

    primary: Planner
    """A planner (``LearnedPlanner``, ``PPOPlanner``...)."""
    fallback: Planner
    """The planner whose action stands where the primary's look-ahead fails."""
    psp: PSPParams = struct.field(pytree_node=False)
    """The planner parameters of the look-ahead (each policy keeps its own action box)."""
    steps: int = struct.field(pytree_node=False, default=1)
    """Steps of the look-ahead (>= 1)."""
    strict: bool = struct.field(pytree_node=False, default=True)
    """Take the fallback's action only where its own look-ahead is safe too; where both
    fail, the primary's action stands."""

    def _holds(self, planner, state):
        def one(s):
            walk = plan_steps(s, planner.policy, self.psp, num_steps=self.steps, unroll=True)
            return walk.num_safe_steps == self.steps

        return over_states(one, state)

    def uses_fallback(self, state):
        """Whether the fallback acts at apex states ``(..., 3)``: the primary's look-ahead
        fails (and, when ``strict``, the fallback's holds)."""
        switch = ~self._holds(self.primary, state)
        if self.strict:
            switch = switch & self._holds(self.fallback, state)
        return switch

    def policy(self, state):
        """The policy for one apex state ``(3,) -> (3,)`` (for plan_steps)."""
        switch = self.uses_fallback(state)
        return jnp.where(switch, self.fallback.policy(state), self.primary.policy(state))

    def mean_action(self, state):
        """Actions for apex states ``(..., 3)`` (jittable, batched over leading axes)."""
        return over_states(self.policy, state)

    def value(self, state):
        """The value of the policy whose action is taken, for apex states ``(..., 3)``."""
        switch = self.uses_fallback(state)
        return jnp.where(switch, self.fallback.value(state), self.primary.value(state))


def make_fallback_planner(
    primary, fallback, steps: int = 1, strict: bool = True
) -> FallbackPlanner:
    """A :class:`FallbackPlanner` whose look-ahead uses the primary's planner parameters."""
    if int(steps) != steps or steps < 1:
        raise ValueError(f"FallbackPlanner.steps must be an int >= 1; got {steps!r}")
    if primary.psp != fallback.psp:
        raise ValueError(
            "FallbackPlanner: the primary and the fallback were trained with different "
            f"planner parameters ({primary.psp} and {fallback.psp})"
        )
    return FallbackPlanner(primary, fallback, primary.psp, int(steps), bool(strict))


class FallbackCheckpoint(NamedTuple):
    """What a fallback checkpoint's ``fallback.json`` holds."""

    primary: Path
    """The primary policy's checkpoint folder."""
    fallback: Path
    """The fallback policy's checkpoint folder."""
    steps: int
    """Steps of the look-ahead."""
    strict: bool
    """See :attr:`FallbackPlanner.strict`."""


def write_fallback_checkpoint(path, primary, fallback, steps: int, strict: bool) -> Path:
    """Write ``fallback.json`` at ``path`` naming the checkpoint folders ``primary`` and
    ``fallback`` (stored relative to ``path`` when they lie beside or inside it, so the
    three folders move together; else absolute); returns ``path``. Checks nothing: use
    :func:`jaxloco.learning.loading.save_fallback_checkpoint`."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)

    def relative(p):
        p = Path(p).resolve()
        if p.is_relative_to(path.resolve().parent):
            return os.path.relpath(p, path.resolve())
        return str(p)

    meta = {
        "format_version": FORMAT_VERSION,
        "primary": relative(primary),
        "fallback": relative(fallback),
        "steps": int(steps),
        "strict": bool(strict),
    }
    (path / FALLBACK_FILE).write_text(json.dumps(meta, indent=2) + "\n")
    return path


def read_fallback_checkpoint(path) -> FallbackCheckpoint:
    """The contents of the fallback checkpoint folder ``path`` (its policies' folders
    resolved against it)."""
    path = Path(path)
    meta = json.loads((path / FALLBACK_FILE).read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"{path / FALLBACK_FILE}: format {meta.get('format_version')!r}, "
            f"expected {FORMAT_VERSION}"
        )
    found = FallbackCheckpoint(
        path / meta["primary"], path / meta["fallback"], int(meta["steps"]), bool(meta["strict"])
    )
    for role in ("primary", "fallback"):
        if not getattr(found, role).is_dir():
            raise FileNotFoundError(
                f"{path / FALLBACK_FILE}: its {role} {getattr(found, role)} is missing"
            )
    return found
