"""Where recovery ends: the largest recovered impulse per direction and phase, by bisection.

A grid sweep says which of the pushes it tried were recovered; it cannot say how strong a
push the robot takes when every push it tried was recovered. :func:`search_limits` finds,
for every cell (direction x single-support phase x push duration x replanning on/off), the
largest impulse the walking controller recovers, by bisection over the impulse:

- every round tests each cell at the middle of its bracket ``[lo, hi]`` (N s), with
  ``replicas`` runs from the undisturbed walk's state plus small joint-velocity noise
  (``qvel_noise``, a new draw per run), so one lucky run does not set the limit;
- the impulse counts as recovered when at least ``min_recovered`` of the replicas are
  (then ``lo`` moves up to it), else ``hi`` moves down to it. A round runs all replicas
  but the last first, and the last only for the cells they leave undecided (exactly
  ``min_recovered - 1`` recovered): the decisions are those of running every replica, at
  fewer runs;
- after ``rounds`` rounds the cell's **limit** is ``lo``: the largest impulse tested that
  was recovered, every smaller impulse tested in that cell having been recovered too (the
  bisection only tests above ``lo``). Its resolution is the final bracket's width,
  ``(impulse_range[1] - impulse_range[0]) / 2**rounds``.

The bracket's ends are assumed, not tested: a cell that recovered every impulse it tried is
**censored above** (its limit is at least ``lo``, maybe past the range), and one that
recovered none is **censored below** (its limit is under the first impulse tried); the
result says which. The push's force is the impulse over its duration.

Each round is one or two sweeps (:func:`~jaxloco.sweep.run.run_table`) into
``run_dir/round_NN`` and ``run_dir/round_NN_last``, all sharing one folder of undisturbed
walks; a round's pushes follow from the
earlier rounds' outcomes on disk, so running the same search again resumes where it
stopped, and its results do not depend on where the chunks ran.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np

from jaxloco import validation as v
from jaxloco.robots import DEFAULT_ROBOT
from jaxloco.runtime import to_jsonable
from jaxloco.sweep.spec import PushTable

PAPER_IMPULSE = 52.0
"""The paper's push: 520 N for 0.1 s (N s)."""
PAPER_MASS = 135.9
"""The paper's robot's mass (kg): its push, 520 N for 0.1 s, is a velocity change of
``PAPER_IMPULSE / PAPER_MASS`` = 0.383 m/s."""


def paper_impulse_for(mass: float | None) -> float:
    """The paper's push for a robot of ``mass`` kg: the same velocity change (N s, to 0.01;
    52 N s for the paper's robot or when ``mass`` is None)."""
    return PAPER_IMPULSE if mass is None else round(PAPER_IMPULSE * mass / PAPER_MASS, 2)


@dataclasses.dataclass(frozen=True)
class LimitSearch:
    """The cells searched and how (see the module doc). The defaults are ``make run``'s:
    8 directions x 5 phases x replanning on and off, 4 rounds of up to 5 replicas (at most
    1,600 pushes; resolution 8 N s)."""

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
    impulse_range: tuple[float, float] = (0.0, 128.0)
    """The bisection's initial bracket (N s), over twice the paper's 52."""
    rounds: int = 4
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


@dataclasses.dataclass(frozen=True)
class LimitResult:
    """Per cell (the order of :meth:`LimitSearch.cells`), what the search found."""

    search: LimitSearch
    """The search's settings."""
    cells: list
    """``(direction_deg, phase, duration, replan)`` per cell."""
    brackets: Brackets
    """Per cell, the final bracket: the largest recovered and the smallest failed impulse (N s)."""
    tested: np.ndarray
    """(rounds, C) impulse tested in each round (N s)."""
    recovered: np.ndarray
    """(rounds, C) replicas recovered in each round."""
    runs: np.ndarray
    """(rounds, C) replicas run in each round (the last only where the others left the
    decision open)."""
    rounds_done: int
    """Rounds with results for every cell (< ``search.rounds``: the search was stopped)."""

    @property
    def limit(self) -> np.ndarray:
        """(C,) the largest recovered impulse (N s; see the module doc)."""
        return self.brackets.lo

    @property
    def censored_above(self) -> np.ndarray:
        """(C,) every impulse tried was recovered: the limit may lie past the range."""
        return ~self.brackets.hi_tested

    @property
    def censored_below(self) -> np.ndarray:
        """(C,) no impulse tried was recovered: the limit lies under the first one tried."""
        return ~self.brackets.lo_tested

    def summary(self, mass: float | None = None) -> dict:
        """Every number of the search, JSON-ready. With the robot's ``mass`` (kg) the limits
        are also given as velocity changes (impulse / mass, m/s), and the paper's push is
        the same velocity change as the paper's 52 N s (:func:`paper_impulse_for`)."""
        s = self.search
        paper = paper_impulse_for(mass)
        rows = []
        for k, (d, p, t, r) in enumerate(self.cells):
            rows.append(
                {
                    "direction_deg": d,
                    "phase": p,
                    "duration_s": t,
                    "replan": r,
                    "limit_Ns": float(self.limit[k]),
                    "bracket_Ns": [float(self.brackets.lo[k]), float(self.brackets.hi[k])],
                    "censored_above": bool(self.censored_above[k]),
                    "censored_below": bool(self.censored_below[k]),
                    "at_least_paper": bool(self.limit[k] >= paper),
                    "tested_Ns": self.tested[: self.rounds_done, k].tolist(),
                    "recovered_replicas": self.recovered[: self.rounds_done, k].tolist(),
                    "replicas_run": self.runs[: self.rounds_done, k].tolist(),
                }
            )
        variants = {}
        for r in s.replan:
            for t in s.durations:
                sel = [k for k, c in enumerate(self.cells) if c[3] == r and c[2] == t]
                lim = self.limit[sel]
                name = f"{'replan' if r else 'no_replan'}, {t:g} s"
                per_dir = {}
                for d in s.directions_deg:
                    cells = [k for k in sel if self.cells[k][0] == d]
                    per_dir[f"{d:g}"] = float(np.min(self.limit[cells]))
                variants[name] = {
                    "replan": bool(r),
                    "duration_s": float(t),
                    "median_limit_Ns": float(np.median(lim)),
                    "min_limit_Ns": float(np.min(lim)),
                    "max_limit_Ns": float(np.max(lim)),
                    "cells_at_least_paper": int(np.sum(lim >= paper)),
                    "cells": len(sel),
                    "worst_phase_limit_per_direction_Ns": per_dir,
                }
                if mass is not None:
                    for key in ("median", "min", "max"):
                        v_ns = variants[name][f"{key}_limit_Ns"]
                        variants[name][f"{key}_limit_mps"] = v_ns / mass
        if mass is not None:
            for row in rows:
                row["limit_mps"] = row["limit_Ns"] / mass
        extra = {} if mass is None else {"robot_mass_kg": mass, "paper_velocity_mps": paper / mass}
        return to_jsonable(
            {
                "search": dataclasses.asdict(s),
                **extra,
                "paper_impulse_Ns": paper,
                "resolution_Ns": s.resolution(),
                "rounds_done": self.rounds_done,
                "pushes_run": int(self.runs[: self.rounds_done].sum()),
                "variants": variants,
                "cells": rows,
            }
        )


def search_limits(
    search: LimitSearch,
    run_dir,
    run_round,
    progress: bool = True,
) -> LimitResult:
    """Run (or resume) ``search`` into ``run_dir``. ``run_round(table, round_dir,
    walks_dir) -> outcomes`` runs the pushes of a stage of a round (a
    :func:`~jaxloco.sweep.run.run_table` call: the ``recovered`` column, one entry per
    row, every row done)."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    _check_run_dir(search, run_dir)
    cells = search.cells()
    brackets = Brackets.start(search)
    tested = np.full((search.rounds, len(cells)), np.nan)
    recovered = np.zeros((search.rounds, len(cells)), int)
    runs = np.zeros((search.rounds, len(cells)), int)
    n, m, s0 = search.replicas, search.min_recovered, search.first_seed
    walks = run_dir / "walks"

    def stage(impulses, which, seeds, name):
        table = round_table(search, impulses, which, seeds)
        ok = np.asarray(run_round(table, run_dir / name, walks), bool)
        if ok.shape != (len(table),):
            raise ValueError(f"run_round gave {ok.shape} outcomes for {len(table)} pushes")
        return ok.reshape(len(which), len(seeds)).sum(axis=1)

    for r in range(search.rounds):
        impulses = brackets.middle()
        if progress:
            print(f"limit search: round {r + 1} of {search.rounds}", flush=True)
        first = range(s0, s0 + n - 1) if n > 1 else range(s0, s0 + 1)
        everyone = np.arange(len(cells))
        recovered[r] = stage(impulses, everyone, first, f"round_{r:02d}")
        runs[r] = len(first)
        open_ = everyone[recovered[r] == m - 1] if n > 1 else everyone[:0]
        if len(open_):
            last = range(s0 + n - 1, s0 + n)
            recovered[r, open_] += stage(impulses, open_, last, f"round_{r:02d}_last")
            runs[r, open_] += 1
        tested[r] = impulses
        brackets = brackets.update(impulses, recovered[r] >= m)
    return LimitResult(search, cells, brackets, tested, recovered, runs, search.rounds)


def _check_run_dir(search: LimitSearch, run_dir: Path) -> None:
    """A run directory belongs to one search: refuse another's rounds."""
    path = run_dir / "search.json"
    mine = to_jsonable(dataclasses.asdict(search))
    mine = json.loads(json.dumps(mine))
    if path.exists():
        # Fields added since a search was written hold their defaults there.
        defaults = json.loads(json.dumps(to_jsonable(dataclasses.asdict(LimitSearch()))))
        theirs = {**defaults, **json.loads(path.read_text())}
        if theirs != mine:
            changed = sorted(k for k in mine if theirs.get(k) != mine[k])
            raise ValueError(
                f"{run_dir} holds another limit search (differs in {', '.join(changed)}); "
                "choose another run directory"
            )
    elif any(run_dir.glob("round_*")):
        raise ValueError(
            f"{run_dir} holds rounds of an unknown search; choose another run directory"
        )
    else:
        path.write_text(json.dumps(mine, indent=2) + "\n")


def run_limit_search(
    search: LimitSearch,
    run_dir,
    backend: str = "c",
    chunk_size: int = 16,
    gait=None,
    physics=None,
    wblc=None,
    push_body: str | None = None,
    workers: int = 0,
    address: str | None = None,
    config: dict | None = None,
    progress: bool = True,
    planner: str | None = None,
    robot: str = DEFAULT_ROBOT.name,
) -> LimitResult:
    """:func:`search_limits` on the walking controller: every round a sweep
    (:func:`~jaxloco.sweep.run.run_table`) on one set of workers kept for the whole search
    (``workers``/``address`` as there; 0: one per core when the rounds are big enough)."""
    import contextlib

    from jaxloco.sweep.chunks import ChunkRunner
    from jaxloco.sweep.run import _auto_workers, make_job, run_table
    from jaxloco.sweep.spec import SweepSpec

    spec = SweepSpec(
        push_step=search.push_step,
        horizon=search.horizon,
        steps_after=search.steps_after,
        qvel_noise=search.qvel_noise,
        fall_height=search.fall_height,
    )
    job = make_job(spec, run_dir, backend, chunk_size, gait, physics, wblc, push_body, robot=robot)
    job = job.replace(planner=None if planner is None else str(planner))
    per_round = len(search.cells()) * search.replicas
    if workers == 0:
        workers = _auto_workers(backend, per_round * search.horizon)
    with contextlib.ExitStack() as stack:
        client = None
        if address or workers > 1:
            from jaxloco.sweep.cluster import dask_client

            client = stack.enter_context(dask_client(address, workers))
        # Here: the walks and the chunk program (in process: the chunks too).
        runner = ChunkRunner(job, make_backend=client is None or bool(job.cache_dir))

        def run_round(table, round_dir, walks_dir):
            round_job = job.replace(run_dir=str(round_dir), walks_dir=str(walks_dir))
            res = run_table(
                table, round_job, config, progress, client=client, runner=runner,
                manifest={"limit_search": dataclasses.asdict(search)},
            )  # fmt: skip
            if not res.complete.all():
                raise RuntimeError(f"{round_dir}: {int((~res.complete).sum())} pushes missing")
            return res.outcomes["recovered"]

        return search_limits(search, run_dir, run_round, progress)
