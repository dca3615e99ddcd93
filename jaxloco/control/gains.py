"""Gains files: WBLC task gains saved as JSON, loaded into any controller config.

A file holds ``{task: {"kp": [...], "kd": [...]}}`` (one number, or one per task row), an
optional ``gait`` section of tuned gait numbers (e.g. ``{"replan_gamma": 0.4}``, applied
with :func:`apply_gait_file`) and free-form metadata. :func:`with_gains` returns a
:class:`WBLCConfig` whose tasks carry those gains as their defaults, so every experiment
that builds a controller from a config runs with tuned gains by passing ``gains_file=PATH``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import jax
import numpy as np

GAIN_KINDS = ("kp", "kd")


def save_gains(
    path: str | os.PathLike, values: dict, meta: dict | None = None, gait: dict | None = None
) -> Path:
    """Write tuned gains (``{task: {"kp": [...], "kd": [...]}}``) as JSON, with ``meta``
    and the tuned gait numbers ``gait`` (``{name: value}``)."""
    for task, g in values.items():
        for kind in GAIN_KINDS:
            arr = np.asarray(g[kind], float)
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"save_gains: {task}.{kind} must be finite and >= 0; got {arr}")
    for name, value in (gait or {}).items():
        if not np.isfinite(float(value)):
            raise ValueError(f"save_gains: gait.{name} must be finite; got {value}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": "jaxloco-gains/1", "gains": values, "meta": meta or {}}
    if gait:
        doc["gait"] = {k: float(v) for k, v in gait.items()}
    path.write_text(json.dumps(jax.tree.map(_plain, doc), indent=2) + "\n")
    return path


def _read(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"gains file {str(path)!r} does not exist")
    doc = json.loads(path.read_text())
    if doc.get("format") != "jaxloco-gains/1" or not isinstance(doc.get("gains"), dict):
        raise ValueError(f"{path}: not a jaxloco gains file (format 'jaxloco-gains/1')")
    return doc


def load_gait(path: str | os.PathLike) -> dict:
    """The gait numbers of a gains file (``{}`` when it has none)."""
    return {k: float(v) for k, v in _read(path).get("gait", {}).items()}


def apply_gait_file(gait_params, path: str | os.PathLike | None):
    """``gait_params`` (a ``GaitParams``) with the gait numbers of the gains file at
    ``path`` (None or "": unchanged); its own checks validate them."""
    if not path:
        return gait_params
    values = load_gait(path)
    fields = {f.name for f in dataclasses.fields(gait_params)}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ValueError(f"{path}: gait numbers {unknown} are not GaitParams fields")
    return dataclasses.replace(gait_params, **values)


def load_gains(path: str | os.PathLike) -> dict:
    """Read a gains file written by :func:`save_gains`: ``{task: {"kp": tuple, "kd": tuple}}``."""
    doc = _read(path)
    return {
        task: {k: tuple(float(x) for x in g[k]) for k in GAIN_KINDS if k in g}
        for task, g in doc["gains"].items()
    }


def _plain(x):
    if isinstance(x, (np.generic, jax.Array, np.ndarray)):
        return np.asarray(x).tolist()
    return x


def with_gains(config, values: dict):
    """``config`` (a :class:`~jaxloco.control.wblc.WBLCConfig`) with the tasks' default gains
    replaced by ``values`` (``{task: {"kp": ..., "kd": ...}}``; tasks not named keep theirs)."""
    names = {t.name for t in config.tasks}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ValueError(f"gains: no task(s) {unknown} in the WBLC config; tasks: {sorted(names)}")
    tasks = tuple(
        dataclasses.replace(
            t, **{k: tuple(float(x) for x in values[t.name][k]) for k in values[t.name]}
        )
        if t.name in values
        else t
        for t in config.tasks
    )
    return dataclasses.replace(config, tasks=tasks)


def apply_gains_file(config, path: str | os.PathLike | None):
    """``config`` with the gains of the file at ``path`` (None or "": unchanged)."""
    return config if not path else with_gains(config, load_gains(path))
