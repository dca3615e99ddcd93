"""One loader for every kind of step-policy checkpoint.

A checkpoint folder says its kind by the file that marks it: ``scaled.json``
(:mod:`~jaxloco.learning.scaled`), ``fallback.json`` (:mod:`~jaxloco.learning.fallback`),
``ppo_params.msgpack`` (:mod:`~jaxloco.learning.ppo`) or ``weights.npz`` (RL-PSP,
:mod:`~jaxloco.learning.checkpoint`). The kinds that wrap other checkpoints (scaled,
fallback) load them through :func:`load_planner` again, so any kind nests in any other.
Each kind's module knows only its own files; this module alone dispatches.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from jaxloco.learning.checkpoint import (
    FALLBACK_FILE,
    PPO_PARAMS_FILE,
    SCALED_FILE,
    files_digest,
    load_learned_planner,
    shipped_path,
)
from jaxloco.learning.fallback import (
    FallbackPlanner,
    make_fallback_planner,
    read_fallback_checkpoint,
    write_fallback_checkpoint,
)
from jaxloco.learning.scaled import (
    ScaledPlanner,
    read_scaled_checkpoint,
    write_scaled_checkpoint,
)
from jaxloco.planner.protocol import Planner
from jaxloco.planner.scaling import FroudeScale


def load_planner(path=None, shipped: str = "default") -> Planner:
    """Load a trained planner from the checkpoint folder ``path``, of any kind (RL-PSP, PPO
    from ``jaxloco train-planner method=ppo``, fallback, scaled); with no path, the policy
    shipped with jaxloco named ``shipped`` (a key of
    :data:`~jaxloco.learning.checkpoint.SHIPPED_POLICIES`). Every kind is a
    :class:`~jaxloco.planner.protocol.Planner`."""
    path = shipped_path(shipped) if path is None else Path(path)
    if (path / SCALED_FILE).exists():
        return load_scaled_planner(path)
    if (path / FALLBACK_FILE).exists():
        return load_fallback_planner(path)
    if (path / PPO_PARAMS_FILE).exists():
        # Imported here, not for a cycle: Brax loads only for PPO checkpoints, not for
        # every walking controller.
        from jaxloco.learning.ppo import load_ppo_planner  # noqa: PLC0415

        return load_ppo_planner(path)
    return load_learned_planner(path)


def checkpoint_digest(path=None, shipped: str = "default") -> str:
    """A short SHA-256 of the files a planner is loaded from (``path``, or the shipped
    policy ``shipped``): the same digest means the same policy, wherever it lies."""
    path = shipped_path(shipped) if path is None else Path(path)
    if (path / SCALED_FILE).exists():
        return scaled_digest(path)
    if (path / FALLBACK_FILE).exists():
        return fallback_digest(path)
    return files_digest(path)


def load_fallback_planner(path) -> FallbackPlanner:
    """The :class:`~jaxloco.learning.fallback.FallbackPlanner` of a fallback checkpoint."""
    found = read_fallback_checkpoint(path)
    return make_fallback_planner(
        load_planner(found.primary), load_planner(found.fallback), found.steps, found.strict
    )


def save_fallback_checkpoint(path, primary, fallback, steps: int = 1, strict: bool = True) -> Path:
    """Write a fallback checkpoint at ``path`` naming the checkpoint folders ``primary`` and
    ``fallback`` (stored relative to ``path`` when they lie beside or inside it, so the
    three folders move together; else absolute), after checking that the two load and
    combine; returns ``path``."""
    make_fallback_planner(load_planner(primary), load_planner(fallback), steps, strict)
    return write_fallback_checkpoint(path, primary, fallback, steps, strict)


def fallback_digest(path) -> str:
    """A short SHA-256 of a fallback checkpoint: its look-ahead and both policies' digests."""
    found = read_fallback_checkpoint(path)
    h = hashlib.sha256(f"steps={found.steps} strict={found.strict}".encode())
    for p in (found.primary, found.fallback):
        h.update(checkpoint_digest(p).encode())
    return h.hexdigest()[:16]


def load_scaled_planner(path) -> ScaledPlanner:
    """The :class:`~jaxloco.learning.scaled.ScaledPlanner` of a scaled checkpoint."""
    found = read_scaled_checkpoint(path)
    return ScaledPlanner(load_planner(found.reference), found.scale)


def save_scaled_checkpoint(path, reference, scale: FroudeScale, robot: str = "") -> Path:
    """Write a scaled checkpoint at ``path``: ``reference`` (a checkpoint folder of any
    kind, learned at the reference size; refused now if it does not load) serving a robot
    of ``scale`` (``robot``: its name, for the record); returns ``path``."""
    load_planner(reference)
    return write_scaled_checkpoint(path, reference, scale, robot)


def scaled_digest(path) -> str:
    """A short SHA-256 of a scaled checkpoint: its scale and its reference's digest."""
    found = read_scaled_checkpoint(path)
    h = hashlib.sha256(f"length_scale={found.scale.length!r}".encode())
    h.update(checkpoint_digest(found.reference).encode())
    return h.hexdigest()[:16]
