"""What a push sweep runs: the specification and its table of pushes.

A :class:`SweepSpec` is plain numbers and lists (a hydra structured-config node). In
``grid`` mode every combination of its lists is one push; in ``random`` mode ``num_random``
pushes are drawn uniformly from the ranges the lists span (directions over the circle).
:func:`expand` turns it into a :class:`PushTable`: one row per push, in a fixed order, so
row ``i`` is the same push however the sweep is chunked or sharded.

Gait phase: each push starts during the single support of step ``push_step`` of the
undisturbed walk, at ``phase`` in (0, 1) of it (0: lift-off, 1: the planned touch-down).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json

import numpy as np

from jaxloco import validation as v

COLUMNS = (
    "direction_deg",
    "magnitude",
    "duration",
    "phase",
    "apex_speed",
    "turn_deg",
    "replan",
    "seed",
)
LIST_FIELDS = (
    "directions_deg",
    "magnitudes",
    "durations",
    "phases",
    "apex_speeds",
    "turns_deg",
    "replan",
    "seeds",
)


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A push sweep (``jaxloco push-sweep task=grid``). The defaults: 8 directions x 2
    impulses (26 and 52 N s, the paper's 520 N x 0.1 s) x 2 phases of step 4's single
    support, replanning on and off: 64 pushes."""

    directions_deg: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)
    """Where the force points in the walking frame at the push (0: forward, i.e. a push
    from behind; 90: to the robot's left)."""
    magnitudes: tuple[float, ...] = (260.0, 520.0)
    """Force (N)."""
    durations: tuple[float, ...] = (0.1,)
    """Push duration (s)."""
    phases: tuple[float, ...] = (0.3, 0.7)
    """Fraction of the single support of step ``push_step`` at which the push starts."""
    apex_speeds: tuple[float, ...] = (1.0,)
    """Cap on the planner's apex velocity (m/s, ``GaitParams.max_apex_speed``): walking
    speed. Values >= 0.37 leave the shipped policy's own speed."""
    turns_deg: tuple[float, ...] = (0.0,)
    """Heading change per step while walking (deg)."""
    replan: tuple[bool, ...] = (True, False)
    """Eq. 33-34 replanning on / off."""
    seeds: tuple[int, ...] = (0,)
    """Noise seeds (replicas of each push)."""
    mode: str = "grid"
    """``grid`` or ``random``."""
    num_random: int = 64
    """Pushes drawn in ``random`` mode."""
    push_step: int = 4
    """The step (counted from the first lift-off) during which pushes start."""
    horizon: float = 2.5
    """Simulated seconds from the push's start."""
    steps_after: int = 2
    """Steps that must begin after the push for it to count as recovered."""
    qvel_noise: float = 0.0
    """Std of noise added to every joint velocity at the push's start (per seed and push;
    0: seeds only matter in random mode)."""
    fall_height: float = 0.7
    """Pelvis height below which the robot has fallen (m)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.one_of(self, "mode", ("grid", "random")),
                v.integer(self, "num_random", 1),
                v.integer(self, "push_step", 1),
                *v.positive(self, "horizon", "fall_height"),
                v.integer(self, "steps_after", 0),
                *v.non_negative(self, "qvel_noise"),
                *((name, len(getattr(self, name)) > 0, "a non-empty list") for name in LIST_FIELDS),
                ("magnitudes", all(m >= 0 for m in self.magnitudes), "values >= 0 (N)"),
                ("durations", all(d > 0 for d in self.durations), "values > 0 (s)"),
                ("phases", all(0 < p < 1 for p in self.phases), "values in (0, 1)"),
                ("apex_speeds", all(x > 0 for x in self.apex_speeds), "values > 0 (m/s)"),
                ("turns_deg", all(abs(t) <= 45 for t in self.turns_deg), "values in [-45, 45]"),
                ("seeds", all(int(s) == s and s >= 0 for s in self.seeds), "integers >= 0"),
            ],
        )

    def digest(self) -> str:
        """A short hash of every field: a run directory belongs to one spec."""
        text = json.dumps(dataclasses.asdict(self), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclasses.dataclass(frozen=True)
class PushTable:
    """One row per push; every column a numpy array of the same length."""

    columns: dict
    """Column name -> (pushes,) numpy array."""

    def __len__(self) -> int:
        return len(self.columns["direction_deg"])

    def __getitem__(self, name) -> np.ndarray:
        return self.columns[name]

    def rows(self, index) -> PushTable:
        return PushTable({k: v[index] for k, v in self.columns.items()})


def expand(spec: SweepSpec) -> PushTable:
    """The pushes of ``spec`` (see the module doc)."""
    lists = [getattr(spec, name) for name in LIST_FIELDS]
    if spec.mode == "grid":
        rows = list(itertools.product(*lists))
        cols = {name: np.array([r[k] for r in rows]) for k, name in enumerate(COLUMNS)}
    else:
        # One stream for the whole table: the same spec always gives the same rows.
        rng = np.random.default_rng(list(spec.seeds))
        n = spec.num_random

        def span(values):
            return (
                rng.uniform(min(values), max(values), n)
                if len(values) > 1
                else (np.full(n, values[0], float))
            )

        cols = {
            "direction_deg": rng.uniform(0.0, 360.0, n)
            if len(spec.directions_deg) > 1
            else np.full(n, float(spec.directions_deg[0])),
            "magnitude": span(spec.magnitudes),
            "duration": span(spec.durations),
            "phase": span(spec.phases),
            "apex_speed": rng.choice(np.asarray(spec.apex_speeds, float), n),
            "turn_deg": rng.choice(np.asarray(spec.turns_deg, float), n),
            "replan": rng.choice(np.asarray(spec.replan, bool), n),
            "seed": rng.choice(np.asarray(spec.seeds, int), n),
        }
    cols = {
        k: v.astype(bool if k == "replan" else int if k == "seed" else float)
        for k, v in cols.items()
    }
    return PushTable(cols)
