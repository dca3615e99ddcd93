"""A sweep's chunks run side by side in worker processes, one per CPU core.

Why processes: the batched WBLC tick keeps one core busy, not two, so one pinned process
per core does the most work; two Python threads calling the same jitted controller at once
hung inside XLA:CPU (``docs/sweep.md``).

The parent walks the undisturbed walks first (they are kept on disk) and, when JAX's
persistent compilation cache is on, compiles the chunk's tick into it; then it starts
``workers`` processes (``spawn``): worker ``k`` is pinned to the ``k``-th core, runs the
MuJoCo C batch with one thread and takes every ``workers``-th remaining chunk. Each chunk
is the same program on the same inputs as in a single process, and is written by its
worker the same atomic way (:mod:`.store`), so results do not depend on ``workers`` and an
interrupted run resumes. The parent shows the progress bar and writes the manifest. A
worker that fails stops the run with its exit status; workers die with the parent.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import queue as queue_module
import time

import jax
import numpy as np
from tqdm.auto import tqdm

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """Linux: have the kernel kill this process when its parent dies (e.g. by the
    parent's watchdog), so no orphaned worker keeps a core busy."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, 9)
    except (OSError, AttributeError):
        pass


def available_cores() -> list[int]:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def _start_on_core(process, core: int) -> None:
    """Start ``process`` already pinned to ``core``: a child inherits the affinity of the
    thread that starts it, so even what it imports before its target runs (the main
    module, under ``spawn``) sees one core."""
    if not hasattr(os, "sched_setaffinity"):
        process.start()
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {core})
    try:
        process.start()
    finally:
        os.sched_setaffinity(0, before)


def _worker_main(worker: int, workers: int, core: int, job_bytes: bytes, results) -> None:
    _die_with_parent()
    if hasattr(os, "sched_setaffinity"):
        # Before anything starts JAX's CPU client (unpickling the job can: it holds
        # arrays), so that its threads share this worker's core and not the others'.
        os.sched_setaffinity(0, {core})
    job = pickle.loads(job_bytes)
    jax.config.update("jax_enable_x64", job["x64"])
    if job["cache_dir"]:
        from jaxloco.runtime import enable_compilation_cache

        enable_compilation_cache(job["cache_dir"])
    from jaxloco.sweep import run as sweep_run
    from jaxloco.sweep.store import SweepStore

    spec, chunk_size = job["spec"], job["chunk_size"]
    store = SweepStore(job["run_dir"])
    table = store.load_table()
    chunks = sweep_run._chunks(len(table), chunk_size)
    mine = job["todo"][worker::workers]
    ctx = sweep_run._prepare(
        spec, store, table, chunks, mine, job["backend"], job["gait"], job["physics"],
        job["wblc"], job["push_body"], 1, progress=False,
    )  # fmt: skip
    times = []
    for index in mine:
        t0 = time.perf_counter()
        sweep_run._run_one_chunk(ctx, spec, store, table, chunks[index], index, chunk_size)
        times.append(time.perf_counter() - t0)
    results.put({"worker": worker, "chunk_times": times, "walks_s": ctx.walks_s})


def run_in_workers(
    spec, store, table, chunks, todo, backend, chunk_size, gait, physics, wblc, push_body,
    workers, progress,
):  # fmt: skip
    """Run the chunks ``todo`` in ``workers`` processes; append the run to the manifest."""
    from jaxloco.sweep import run as sweep_run

    t_start = time.perf_counter()
    # The undisturbed walks, once, here: the workers load them from disk.
    cache_dir = jax.config.jax_compilation_cache_dir
    walks = sweep_run._prepare(
        spec, store, table, chunks, todo, backend, gait, physics, wblc, push_body, None,
        progress, make_runner=bool(cache_dir),
    )  # fmt: skip
    if cache_dir:
        # Compile the chunk's tick here, on every core, into the persistent cache (one
        # tick of the first chunk, results discarded): the workers then load it instead
        # of each compiling it on one core. With chunks of 20, a worker's first
        # chunk took 90 s when it compiled the tick, 48 s when it loaded it.
        first = sweep_run._chunk_starts(walks, spec, table, chunks[todo[0]], chunk_size)
        walks.runner.run(first, 1)
    cores = available_cores()
    job = {
        "spec": spec,
        "run_dir": str(store.dir),
        "todo": list(todo),
        "backend": backend,
        "chunk_size": chunk_size,
        "gait": gait,
        "physics": physics,
        "wblc": wblc,
        "push_body": push_body,
        "cores": cores,
        "x64": bool(jax.config.jax_enable_x64),
        "cache_dir": cache_dir,
    }
    mp = multiprocessing.get_context("spawn")
    results = mp.Queue()
    procs = [
        mp.Process(
            target=_worker_main,
            args=(k, workers, cores[k % len(cores)], pickle.dumps(job), results),
            daemon=True,
        )
        for k in range(workers)
    ]
    t_workers = time.perf_counter()
    for k, p in enumerate(procs):
        _start_on_core(p, cores[k % len(cores)])
    horizon = walks.horizon_steps
    pending = list(todo)
    done_rows = sum(len(chunks[i]) for i in range(len(chunks)) if store.done(i) and i not in todo)
    recovered = attempted = 0
    bar = tqdm(
        total=len(table), initial=done_rows, desc=f"push sweep ({backend}, {workers} workers)",
        unit="push", disable=not progress,
    )  # fmt: skip
    reports = []
    try:
        while pending or len(reports) < workers:
            for index in [i for i in pending if store.done(i)]:
                pending.remove(index)
                with np.load(store.chunk_path(index)) as f:
                    recovered += int(f["recovered"].sum())
                    attempted += len(f["rows"])
                bar.update(len(chunks[index]))
                rate = (len(todo) - len(pending)) * chunk_size * horizon
                bar.set_postfix(
                    recovered=f"{recovered}/{attempted}",
                    env_steps_s=f"{rate / (time.perf_counter() - t_workers):.0f}",
                )
            try:
                reports.append(results.get(timeout=0.5))
            except queue_module.Empty:
                pass
            failed = [p for p in procs if p.exitcode not in (None, 0)]
            if failed:
                raise RuntimeError(
                    f"sweep worker exited with status {failed[0].exitcode}; chunks written so "
                    "far are kept, run again to resume"
                )
            if not pending and len(reports) < workers and not any(p.is_alive() for p in procs):
                raise RuntimeError("sweep workers ended without reporting")
    finally:
        bar.close()
        for p in procs:
            if p.is_alive() and len(reports) < workers:
                p.terminate()
            p.join(timeout=30)
    wall_workers = time.perf_counter() - t_workers
    # Each worker's first chunk includes its compile; the steady rate is the workers'
    # steady chunks side by side.
    firsts = [r["chunk_times"][0] for r in reports if r["chunk_times"]]
    steady = [t for r in reports for t in r["chunk_times"][1:]]
    steady_s = float(np.mean(steady)) if steady else None
    manifest = store.read_manifest()
    manifest["runs"].append(
        {
            "chunks": list(todo),
            "workers": workers,
            "cores": cores,
            "undisturbed_walks_s": walks.walks_s,
            "first_chunk_s": max(firsts) if firsts else None,
            "steady_chunk_s": steady_s,
            "env_steps_per_s": None
            if steady_s is None
            else workers * chunk_size * horizon / steady_s,
            "workers_wall_s": wall_workers,
            "overall_env_steps_per_s": len(todo) * chunk_size * horizon / wall_workers,
            "wall_s": time.perf_counter() - t_start,
        }
    )
    store.write_manifest(manifest)
