"""What a limit search found, per cell (:class:`LimitResult`), and its JSON summary."""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxloco.runtime import to_jsonable
from jaxloco.sweep.limit_search import (
    Brackets,
    LimitSearch,
    learned_impulse_for,
    paper_impulse_for,
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
        the same velocity change as the paper's 52 N s (:func:`paper_impulse_for`), and so is
        the learned policy's 108 N s (:func:`learned_impulse_for`)."""
        s = self.search
        paper = paper_impulse_for(mass)
        learned = learned_impulse_for(mass)
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
                    "at_least_learned": bool(self.limit[k] >= learned),
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
                    "cells_at_least_learned": int(np.sum(lim >= learned)),
                    "cells_censored_above": int(np.sum(self.censored_above[sel])),
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
                "learned_impulse_Ns": learned,
                "resolution_Ns": s.resolution(),
                "rounds_done": self.rounds_done,
                "pushes_run": int(self.runs[: self.rounds_done].sum()),
                "variants": variants,
                "cells": rows,
            }
        )
