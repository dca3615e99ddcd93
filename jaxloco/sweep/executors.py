"""Running a sweep's chunks in this process, and what every executor shares.

Every executor (this one; :mod:`.cluster` on Dask distributed) runs a chunk through the
same :class:`~jaxloco.sweep.chunks.ChunkRunner`, so the outcomes are the same bit for bit
wherever a chunk ran, and every one leaves the chunk files in the run directory
(:mod:`.store`), which is what resuming reads.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Sequence

import numpy as np
from tqdm.auto import tqdm

from jaxloco.sweep.chunks import ChunkReport, ChunkRunner
from jaxloco.sweep.job import SweepJob


def available_cores() -> list[int]:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def pin_process(core: int) -> None:
    """Pin every thread of this process (and so every thread it starts later) to ``core``
    (Linux; elsewhere nothing happens)."""
    if not hasattr(os, "sched_setaffinity"):
        return
    tasks = "/proc/self/task"
    for tid in os.listdir(tasks) if os.path.isdir(tasks) else [0]:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(int(tid), {core})


def run_in_process(
    job: SweepJob,
    todo: Sequence[int],
    progress: bool = True,
    runner: ChunkRunner | None = None,
) -> dict:
    """Run the chunks ``todo`` of ``job`` here, one after another; returns the run's
    record for the manifest. ``runner``: one to reuse (with ``job``'s settings)."""
    t_start = time.perf_counter()
    runner = runner or ChunkRunner(job)
    walks_s = runner.prepare_walks(job, todo, progress)
    steps = [0]

    def tick_progress(n):
        steps[0] += n

    reports = []
    with progress_bar(runner.sweep(job), todo, f"push sweep ({job.backend})", progress) as bar:
        for index in todo:
            before = steps[0]
            report = runner.run_chunk(job, index, tick_progress)
            reports.append(report)
            bar.advance(report, (steps[0] - before) / report.seconds)
    return run_record(todo, reports, walks_s, time.perf_counter() - t_start, {})


class _Bar:
    """The sweep's progress bar: pushes done, recovered so far, env-steps per second."""

    def __init__(self, bar):
        self.bar = bar
        self.recovered = self.attempted = 0

    def advance(self, report: ChunkReport, env_steps_per_s: float) -> None:
        self.recovered += report.recovered
        self.attempted += report.pushes
        self.bar.update(report.pushes)
        self.bar.set_postfix(
            recovered=f"{self.recovered}/{self.attempted}", env_steps_s=f"{env_steps_per_s:.0f}"
        )


@contextlib.contextmanager
def progress_bar(runner: ChunkRunner, todo, label: str, progress: bool):
    """A :class:`_Bar` over the sweep's pushes, starting at those already on disk."""
    todo = set(todo)
    done = sum(
        len(rows)
        for i, rows in enumerate(runner.chunks)
        if i not in todo and runner.store.done(i, rows)
    )
    bar = tqdm(total=len(runner.table), initial=done, desc=label, unit="push", disable=not progress)
    try:
        yield _Bar(bar)
    finally:
        bar.close()


def run_record(todo, reports: list[ChunkReport], walks_s: float, wall_s: float, extra: dict):
    """The manifest's record of one run: which chunks, and how fast. ``reports`` in the
    order the chunks finished. The first chunk each worker runs includes its start (and
    compile), so the steady rate is over the later ones, the workers side by side: their
    number times a chunk's env-steps over the mean steady chunk time (None without any)."""
    by_worker: dict[str, list[ChunkReport]] = {}
    for r in reports:
        by_worker.setdefault(r.worker, []).append(r)
    firsts = [rs[0].seconds for rs in by_worker.values()]
    steady = [r.seconds for rs in by_worker.values() for r in rs[1:]]
    steady_s = float(np.mean(steady)) if steady else None
    chunk_steps = reports[0].env_steps if reports else 0
    env_steps = sum(r.env_steps for r in reports)
    return {
        "chunks": [int(i) for i in todo],
        "undisturbed_walks_s": walks_s,
        "first_chunk_s": max(firsts) if firsts else None,
        "steady_chunk_s": steady_s,
        "env_steps_per_s": None if steady_s is None else len(by_worker) * chunk_steps / steady_s,
        "overall_env_steps_per_s": env_steps / wall_s if wall_s > 0 else None,
        "wall_s": wall_s,
        **extra,
    }
