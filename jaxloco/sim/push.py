"""External pushes: a force on a body (the pelvis) for a while, as ``xfrc_applied``.

A :class:`Push` is plain numbers (a hydra config node); :func:`push_force` evaluates a push
given as arrays, so it works inside ``jit``/``vmap`` (MJX rollouts) and from Python (the C
backend) alike. ``direction_deg`` is the direction the force points, in the world's
horizontal plane: 0 pushes towards +x (the initial walking direction, i.e. a push from
behind), 90 towards +y (a push from the robot's right side).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class Push:
    magnitude: float = 520.0
    """Force (N)."""
    direction_deg: float = 0.0
    start: float = 3.0
    """Time the push begins (s)."""
    duration: float = 0.1
    body: str = "pelvis"

    def __post_init__(self):
        finite = all(math.isfinite(getattr(self, n)) for n in ("magnitude", "start", "duration"))
        v.check_fields(
            self,
            [
                ("magnitude", self.magnitude >= 0 and finite, ">= 0"),
                ("direction_deg", math.isfinite(self.direction_deg), "finite"),
                ("start", self.start >= 0 and finite, ">= 0"),
                ("duration", self.duration > 0 and finite, "> 0"),
            ],
        )

    @property
    def impulse(self) -> float:
        """N s."""
        return self.magnitude * self.duration

    def as_array(self) -> np.ndarray:
        """``(magnitude, direction_rad, start, duration)`` for :func:`push_force`."""
        return np.array(
            [self.magnitude, math.radians(self.direction_deg), self.start, self.duration]
        )


def push_force(push, t):
    """World force (3,) at time ``t`` of a push ``(magnitude, direction_rad, start,
    duration)``; zero outside ``[start, start + duration)``."""
    push = jnp.asarray(push)
    magnitude, direction, start, duration = push[0], push[1], push[2], push[3]
    on = (t >= start) & (t < start + duration)
    f = jnp.where(on, magnitude, 0.0)
    return jnp.stack([f * jnp.cos(direction), f * jnp.sin(direction), 0.0 * f])


def body_index(model: mujoco.MjModel, name: str) -> int:
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if body < 0:
        raise ValueError(f"Push.body: no body {name!r} in the model")
    return body


def apply_push_c(model: mujoco.MjModel, data: mujoco.MjData, pushes, body: int) -> None:
    """Set ``data.xfrc_applied[body]`` to the sum of ``pushes`` (rows of
    :meth:`Push.as_array`) at ``data.time`` (MuJoCo C backend)."""
    force = np.zeros(3)
    for p in np.atleast_2d(pushes):
        magnitude, direction, start, duration = p
        if start <= data.time < start + duration:
            force += magnitude * np.array([math.cos(direction), math.sin(direction), 0.0])
    data.xfrc_applied[body, :3] = force
    data.xfrc_applied[body, 3:] = 0.0
