"""The limit search on the walking controller: :func:`~.bisection.search_limits` with every
round a sweep (:func:`~jaxloco.sweep.run.run_table`) on one set of workers, in this
process or on Dask, kept for the whole search."""

from __future__ import annotations

import contextlib
import dataclasses

from jaxloco.robots import DEFAULT_ROBOT
from jaxloco.sweep.bisection import search_limits
from jaxloco.sweep.chunks import ChunkRunner
from jaxloco.sweep.limit_result import LimitResult
from jaxloco.sweep.limit_search import LimitSearch
from jaxloco.sweep.run import _auto_workers, make_job, run_table
from jaxloco.sweep.spec import SweepSpec


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
            # Dask's import is heavy: only a search on workers pays for it.
            from jaxloco.sweep.cluster import dask_client  # noqa: PLC0415

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
