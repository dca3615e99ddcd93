"""A step policy learned at one robot size, serving a robot of another size (Froude
scaling, :mod:`jaxloco.planner.scaling`): :class:`ScaledPlanner`, and its checkpoint, a
folder with ``scaled.json`` (the robot's scale and the reference-size checkpoint it
wraps)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import NamedTuple

from flax import struct

from jaxloco.learning.checkpoint import SCALED_FILE
from jaxloco.learning.evaluation import over_states
from jaxloco.learning.starts import StartStates
from jaxloco.planner import FroudeScale, Planner, PSPParams, scale_psp


@struct.dataclass
class ScaledPlanner:
    """``planner`` (learned at the reference size) for a robot ``scale`` times that size.

    Apex states are taken to the reference's units before ``planner`` sees them and its
    actions brought back; ``psp`` is the planner's parameters at this size. The planners'
    interface (``policy``, ``mean_action``, ``value``, ``psp``); a pytree."""

    planner: Planner
    """The planner at the reference size (``LearnedPlanner``, ``FallbackPlanner``...)."""
    scale: FroudeScale = struct.field(pytree_node=False)
    """The robot's size relative to the reference's (static)."""

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


FORMAT_VERSION = 1


class ScaledCheckpoint(NamedTuple):
    """What a scaled checkpoint's ``scaled.json`` holds."""

    reference: Path
    """The checkpoint folder of the planner learned at the reference size."""
    scale: FroudeScale
    """The robot's size relative to the reference."""
    robot: str
    """The robot's name, for the record."""


def write_scaled_checkpoint(path, reference, scale: FroudeScale, robot: str = "") -> Path:
    """Write ``scaled.json`` at ``path``: ``reference`` (a checkpoint folder of any kind,
    learned at the reference size) serving a robot of ``scale`` (``robot``: its name).
    ``reference`` is stored relative to ``path`` when it lies beside or inside it (the
    folders move together), else absolute; returns ``path``. Checks nothing: use
    :func:`jaxloco.learning.loading.save_scaled_checkpoint`."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    reference = Path(reference).resolve()
    stored = (
        os.path.relpath(reference, path.resolve())
        if reference.is_relative_to(path.resolve().parent)
        else str(reference)
    )
    meta = {
        "format_version": FORMAT_VERSION,
        "robot": robot,
        "length_scale": float(scale.length),
        "reference": stored,
    }
    (path / SCALED_FILE).write_text(json.dumps(meta, indent=2) + "\n")
    return path


def read_scaled_checkpoint(path) -> ScaledCheckpoint:
    """The contents of the scaled checkpoint folder ``path`` (its reference resolved
    against it)."""
    path = Path(path)
    meta = json.loads((path / SCALED_FILE).read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"{path / SCALED_FILE}: format {meta.get('format_version')!r}, "
            f"expected {FORMAT_VERSION}"
        )
    reference = path / meta["reference"]
    if not reference.is_dir():
        raise FileNotFoundError(f"{path / SCALED_FILE}: its reference {reference} is missing")
    return ScaledCheckpoint(reference, FroudeScale(float(meta["length_scale"])), meta["robot"])


def scale_box(spec: StartStates, scale: FroudeScale) -> StartStates:
    """``spec``'s apex-state box in a robot of ``scale``'s units (the basin's draw)."""
    units = scale.state_units
    return dataclasses.replace(
        spec,
        box_low=tuple(lo * u for lo, u in zip(spec.box_low, units, strict=True)),
        box_high=tuple(hi * u for hi, u in zip(spec.box_high, units, strict=True)),
    )
