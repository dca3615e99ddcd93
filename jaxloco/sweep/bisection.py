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
import json
from pathlib import Path

import numpy as np

from jaxloco.runtime import to_jsonable
from jaxloco.sweep.limit_result import LimitResult
from jaxloco.sweep.limit_search import Brackets, LimitSearch, round_table


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
