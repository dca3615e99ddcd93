"""External pushes: a force on a body (the pelvis) for a while, as ``xfrc_applied``.

A :class:`Push` is one push as plain numbers (a hydra config node). :class:`PushArrays` is
the one array layout of pushes that every traced consumer takes (MJX rollouts, the sweep
backends, the tuning losses): a pytree of four arrays of the same shape, one entry per push,
so it batches with ``vmap`` and needs no column indices. :func:`push_force` evaluates it
inside ``jit`` and :func:`apply_push_c` from Python (the C backend).

``direction_deg`` is the direction the force points, in the world's horizontal plane: 0
pushes towards +x (the initial walking direction, i.e. a push from behind), 90 towards +y
(a push from the robot's right side).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class Push:
    magnitude: float = 520.0
    """Force (N)."""
    direction_deg: float = 0.0
    """Horizontal direction the force points (deg, world frame): 0 towards +x (from behind at the
    start), 90 towards +y."""
    start: float = 3.0
    """Time the push begins (s)."""
    duration: float = 0.1
    """How long the force acts (s)."""
    body: str = "pelvis"
    """The body it acts on, at its centre of mass."""

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


class PushArrays(NamedTuple):
    """Pushes as arrays: every field has the same shape ``S`` (``()`` for one push, ``(P,)``
    for several, ``(B, P)`` batched...), one entry per push."""

    magnitude: np.ndarray | jnp.ndarray
    """Force (N), >= 0; 0 is no push."""
    direction: np.ndarray | jnp.ndarray
    """Direction the force points (rad), in the frame the consumer states (the world's for
    :func:`push_force`)."""
    start: np.ndarray | jnp.ndarray
    """Time the push begins (s)."""
    duration: np.ndarray | jnp.ndarray
    """How long it lasts (s), > 0."""

    @classmethod
    def of(cls, pushes: Sequence[Push], dtype=np.float64) -> PushArrays:
        """Shape ``(len(pushes),)`` arrays of :class:`Push` configs."""
        rows = [(p.magnitude, math.radians(p.direction_deg), p.start, p.duration) for p in pushes]
        cols = np.asarray(rows, dtype).reshape(len(rows), 4).T
        return cls(*cols)

    @classmethod
    def none(cls, shape=(1,), dtype=np.float64) -> PushArrays:
        """Zero-magnitude pushes (no force), e.g. for a rollout without a disturbance."""
        return cls(*(np.full(shape, v, dtype) for v in (0.0, 0.0, 0.0, 1.0)))

    @classmethod
    def from_pairs(cls, pairs, start, duration, dtype=np.float64, field="pushes") -> PushArrays:
        """Shape ``(P,)`` arrays of ``[force N, direction deg]`` pairs (the compact form the
        experiments' configs take), all starting at ``start`` s for ``duration`` s."""
        if not len(pairs):
            raise ValueError(f"{field}: give at least one [force N, direction deg]")
        for k, p in enumerate(pairs):
            if len(p) != 2 or not (math.isfinite(p[0]) and p[0] >= 0) or not math.isfinite(p[1]):
                raise ValueError(
                    f"{field}[{k}] must be [force N >= 0, direction deg]; got {list(p)}"
                )
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"{field}: duration must be > 0 s; got {duration}")
        pairs = np.asarray(pairs, np.float64)
        n = len(pairs)
        return cls(
            pairs[:, 0].astype(dtype),
            np.radians(pairs[:, 1]).astype(dtype),
            np.full(n, start, dtype),
            np.full(n, duration, dtype),
        )

    def astype(self, dtype) -> PushArrays:
        return PushArrays(*(jnp.asarray(x, dtype) for x in self))


def push_force(pushes: PushArrays, t):
    """World force ``S + (3,)`` at time ``t`` of each push (direction in the world frame);
    zero outside ``[start, start + duration)``."""
    on = (t >= pushes.start) & (t < pushes.start + pushes.duration)
    f = jnp.where(on, pushes.magnitude, 0.0)
    return jnp.stack([f * jnp.cos(pushes.direction), f * jnp.sin(pushes.direction), 0.0 * f], -1)


def body_index(model: mujoco.MjModel, name: str) -> int:
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if body < 0:
        raise ValueError(f"Push.body: no body {name!r} in the model")
    return body


def apply_push_c(model: mujoco.MjModel, data: mujoco.MjData, pushes: PushArrays, body: int) -> None:
    """Set ``data.xfrc_applied[body]`` to the sum of ``pushes`` (world frame) at
    ``data.time`` (MuJoCo C backend)."""
    p = [np.atleast_1d(np.asarray(x, np.float64)) for x in pushes]
    magnitude, direction, start, duration = p
    on = (start <= data.time) & (data.time < start + duration)
    f = np.where(on, magnitude, 0.0)
    force = np.array([np.sum(f * np.cos(direction)), np.sum(f * np.sin(direction)), 0.0])
    data.xfrc_applied[body, :3] = force
    data.xfrc_applied[body, 3:] = 0.0
