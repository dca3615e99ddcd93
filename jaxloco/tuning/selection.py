"""Which tuning iterate to keep: validated on the full task, or by the training loss.

A tuning loss looks a short horizon ahead on MJX; what a user wants is the controller that
does best on the full task on MuJoCo C. So the tuners score every ``every``-th iterate
(and the last) on the full task and keep the best score; iterate 0 is the hand-set
controller, so it is kept when nothing beats it. Without validation, the iterate with the
lowest training loss is kept.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import NamedTuple

from tqdm.auto import tqdm

from jaxloco.tuning.optimize import recorded_params

log = logging.getLogger(__name__)

BY_VALIDATION = "validation"
"""``Selection.by`` when iterates were scored on the full task."""
BY_LOSS = "training loss"
"""``Selection.by`` when the lowest training loss chose."""


class Selection(NamedTuple):
    """The kept iterate and how it was chosen."""

    by: str
    """:data:`BY_VALIDATION` or :data:`BY_LOSS`."""
    iteration: int
    """The kept iterate's index in the tuning history (0: the hand-set parameters)."""
    rows: tuple[dict, ...]
    """Each validated iterate's row, ``validate``'s dict with its ``iteration`` (empty when
    chosen by the loss)."""

    def as_json(self) -> dict:
        """``{"by", "iteration", "rows"}``: what the tuners write to ``validation.json``."""
        return {"by": self.by, "iteration": self.iteration, "rows": list(self.rows)}


def validation_iterates(count: int, every: int) -> list[int]:
    """Every ``every``-th of ``count`` iterates, from 0, and the last."""
    if count < 1 or every < 1:
        raise ValueError(f"validation: count and every must be >= 1; got {count}, {every}")
    return sorted({*range(0, count, every), count - 1})


def select_iterate(
    history: list[dict],
    validate: Callable[[int, dict], dict] | None = None,
    score: Callable[[dict], float] | None = None,
    every: int = 1,
    progress: bool | str = False,
) -> Selection:
    """The iterate of ``history`` (a :class:`~.optimize.TuneResult`'s) to keep.

    ``validate(iteration, params) -> row``: the full task run with that iterate's
    parameters (any JSON-able dict); ``score(row)``: lower is better (``inf`` for a
    fall). The lowest score is kept, the earlier iterate on ties. ``validate`` None: the
    lowest training loss is kept."""
    if not history:
        raise ValueError("select_iterate: the tuning history is empty")
    if validate is None:
        best = min(history, key=lambda h: (h["loss"], h["iteration"]))
        return Selection(BY_LOSS, int(best["iteration"]), ())
    if score is None:
        raise ValueError("select_iterate: validate needs a score")
    picks = validation_iterates(len(history), every)
    desc = progress if isinstance(progress, str) else "validation"
    rows = []
    for it in tqdm(picks, desc=desc, disable=not progress):
        rows.append({"iteration": it, **validate(it, recorded_params(history[it]))})
    kept = min(rows, key=lambda r: (score(r), r["iteration"]))
    return Selection(BY_VALIDATION, int(kept["iteration"]), tuple(rows))


def warn_unless_held_out(seen: Iterable, held_out: Iterable, what: str) -> set:
    """Log a warning when held-out cases (``what``: e.g. "frequencies") are also
    training or validation cases: the held-out measure is then not independent. Returns
    the overlap."""
    overlap = set(seen) & set(held_out)
    if overlap:
        log.warning(
            "held-out %s %s are also training or validation %s: the held-out measure is "
            "then not independent",
            what,
            sorted(overlap),
            what,
        )
    return overlap
