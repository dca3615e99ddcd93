"""What a limit search tests: its cells and bisection settings (:class:`LimitSearch`), the
paper's push it is judged against, each cell's bracket (:class:`Brackets`) and the pushes
of a round (:func:`round_table`). The bisection itself is :mod:`.bisection`."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np

from jaxloco import validation as v
from jaxloco.sweep.spec import PushTable

PAPER_IMPULSE = 52.0
"""The paper's push: 520 N for 0.1 s (N s)."""
PAPER_MASS = 135.9
"""The paper's robot's mass (kg): its push, 520 N for 0.1 s, is a velocity change of
``PAPER_IMPULSE / PAPER_MASS`` = 0.383 m/s."""


LEARNED_IMPULSE = 108.0
"""The largest push reported recovered on the paper's robot by a learned policy (Yuan et
al., 2020; N s): the search's second reference, beyond the paper's."""


def paper_impulse_for(mass: float | None) -> float:
    """The paper's push for a robot of ``mass`` kg: the same velocity change (N s, to 0.01;
    52 N s for the paper's robot or when ``mass`` is None)."""
    return scaled_impulse(PAPER_IMPULSE, mass)


def learned_impulse_for(mass: float | None) -> float:
    """:data:`LEARNED_IMPULSE` for a robot of ``mass`` kg, as the same velocity change on the
    paper's 135.9 kg (N s, to 0.01; 108 N s when ``mass`` is None)."""
    return scaled_impulse(LEARNED_IMPULSE, mass)


def scaled_impulse(impulse: float, mass: float | None) -> float:
    """``impulse`` (N s, on the paper's robot) as the same velocity change on a robot of
    ``mass`` kg (to 0.01 N s; unchanged when ``mass`` is None)."""
    return impulse if mass is None else round(impulse * mass / PAPER_MASS, 2)


@dataclasses.dataclass(frozen=True)
class LimitSearch:
    """The cells searched and how (see the module doc). The defaults are ``make run``'s:
    8 directions x 5 phases x replanning on and off, 5 rounds of up to 5 replicas over
    0-256 N s (at most 2,000 pushes; resolution 8 N s)."""

    directions_deg: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)
    """Where the force points in the walking frame at the push (0: forward, i.e. a push
    from behind; 90: to the robot's left)."""
    phases: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9)
    """Fractions of the single support of step ``push_step`` at which pushes start, in
    (0, 1)."""
    durations: tuple[float, ...] = (0.1,)
    """Push durations (s); a cell per duration (e.g. ``[0.1, 0.2]``)."""
    replan: tuple[bool, ...] = (True, False)
    """Eq. 33-34 replanning on / off."""
    impulse_range: tuple[float, float] = (0.0, 256.0)
    """The bisection's initial bracket (N s): beyond twice the learned policy's 108
    (:data:`LEARNED_IMPULSE`), so that no cell at the paper's 500 N m bound recovers every
    impulse tried (the largest limit found there: 192 N s)."""
    rounds: int = 5
    """Bisection rounds: the limit's resolution is the range over ``2**rounds``."""
    replicas: int = 5
    """Runs per tested impulse, each from a new draw of the start-state noise."""
    min_recovered: int = 4
    """Replicas that must recover for the impulse to count as recovered."""
    first_seed: int = 1
    """Noise seed of the first replica; the replicas use ``first_seed, first_seed + 1,
    ...``. Another value repeats the search on independent noise draws, which shows how
    much of a difference between two searches is the noise's."""
    qvel_noise: float = 0.01
    """Std of the noise added to every joint velocity at the push's start."""
    apex_speed: float = 1.0
    """Cap on the planner's apex velocity (m/s)."""
    turn_deg: float = 0.0
    """Heading change per step while walking (deg)."""
    push_step: int = 4
    """The step (counted from the first lift-off) during which pushes start."""
    horizon: float = 2.5
    """Simulated seconds from the push's start."""
    steps_after: int = 2
    """Steps that must begin after the push for it to count as recovered."""
    fall_height: float = 0.7
    """Pelvis height below which the robot has fallen (m)."""

    def __post_init__(self):
        lo, hi = (tuple(self.impulse_range) + (math.nan, math.nan))[:2]
        v.check_fields(
            self,
            [
                ("directions_deg", len(self.directions_deg) > 0, "a non-empty list (deg)"),
                (
                    "directions_deg",
                    all(math.isfinite(d) for d in self.directions_deg),
                    "finite values (deg)",
                ),
                ("phases", len(self.phases) > 0, "a non-empty list"),
                ("phases", all(0 < p < 1 for p in self.phases), "values in (0, 1)"),
                ("durations", len(self.durations) > 0, "a non-empty list (s)"),
                ("durations", all(d > 0 for d in self.durations), "values > 0 (s)"),
                ("replan", len(self.replan) > 0, "a non-empty list"),
                (
                    "impulse_range",
                    len(self.impulse_range) == 2 and 0 <= lo < hi and math.isfinite(hi),
                    "[low, high] with 0 <= low < high (N s)",
                ),
                v.integer(self, "rounds", 1),
                v.integer(self, "replicas", 1),
                v.integer(self, "first_seed", 0),
                (
                    "min_recovered",
                    int(self.min_recovered) == self.min_recovered
                    and 1 <= self.min_recovered <= self.replicas,
                    f"an integer in [1, replicas = {self.replicas}]",
                ),
                *v.non_negative(self, "qvel_noise"),
                *v.positive(self, "apex_speed", "horizon", "fall_height"),
                ("turn_deg", abs(self.turn_deg) <= 45, "in [-45, 45]"),
                v.integer(self, "push_step", 1),
                v.integer(self, "steps_after", 0),
            ],
        )

    def cells(self) -> list[tuple[float, float, float, bool]]:
        """``(direction_deg, phase, duration, replan)`` of every cell, in a fixed order."""
        return [
            (float(d), float(p), float(t), bool(r))
            for r, t, d, p in itertools.product(
                self.replan, self.durations, self.directions_deg, self.phases
            )
        ]

    def resolution(self) -> float:
        """Width of a cell's final bracket (N s)."""
        lo, hi = self.impulse_range
        return (hi - lo) / 2**self.rounds


FINE_SEARCH = LimitSearch(
    directions_deg=tuple(22.5 * k for k in range(16)),
    phases=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9),
    durations=(0.1, 0.2),
    rounds=6,
)
"""A finer map (``jaxloco push-sweep search=fine``): 16 directions x 9 phases x 0.1 and
0.2 s pushes x replanning on and off, 6 rounds (1.6 N s): 17,280 pushes, a cluster's job."""


@dataclasses.dataclass(frozen=True)
class Brackets:
    """The bisection's state: per cell, the bracket of its limit (N s)."""

    lo: np.ndarray
    """(C,) largest impulse known recovered (the range's low end until one is)."""
    hi: np.ndarray
    """(C,) smallest impulse known not recovered (the range's high end until one is)."""
    lo_tested: np.ndarray
    """(C,) bool: ``lo`` was tested and recovered (else it is the range's assumed end)."""
    hi_tested: np.ndarray
    """(C,) bool: ``hi`` was tested and not recovered."""

    @classmethod
    def start(cls, search: LimitSearch) -> Brackets:
        n = len(search.cells())
        lo, hi = search.impulse_range
        return cls(np.full(n, float(lo)), np.full(n, float(hi)), np.zeros(n, bool),
                   np.zeros(n, bool))  # fmt: skip

    def middle(self) -> np.ndarray:
        return 0.5 * (self.lo + self.hi)

    def update(self, tested: np.ndarray, recovered: np.ndarray) -> Brackets:
        """The brackets after testing each cell at ``tested`` (N s) with outcome
        ``recovered`` (bool per cell)."""
        return Brackets(
            lo=np.where(recovered, tested, self.lo),
            hi=np.where(recovered, self.hi, tested),
            lo_tested=self.lo_tested | recovered,
            hi_tested=self.hi_tested | ~recovered,
        )


def round_table(search: LimitSearch, impulses: np.ndarray, cells=None, seeds=None) -> PushTable:
    """The pushes of (a stage of) one round: each of ``cells`` (indices; default all) at its
    impulse (N s, one per cell of the search), one row per replica seed in ``seeds``
    (default all replicas': ``first_seed, first_seed + 1, ...``; the noise draw also
    depends on the row)."""
    all_cells = search.cells()
    cells = range(len(all_cells)) if cells is None else cells
    seeds = (
        range(search.first_seed, search.first_seed + search.replicas) if seeds is None else seeds
    )
    rows = [
        (d, impulses[c] / t, t, p, r, seed)
        for c in cells
        for d, p, t, r in [all_cells[c]]
        for seed in seeds
    ]
    n = len(rows)
    cols = list(zip(*rows, strict=True))
    return PushTable(
        {
            "direction_deg": np.asarray(cols[0], float),
            "magnitude": np.asarray(cols[1], float),
            "duration": np.asarray(cols[2], float),
            "phase": np.asarray(cols[3], float),
            "apex_speed": np.full(n, float(search.apex_speed)),
            "turn_deg": np.full(n, float(search.turn_deg)),
            "replan": np.asarray(cols[4], bool),
            "seed": np.asarray(cols[5], int),
        }
    )
