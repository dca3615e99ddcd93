"""Shared benchmark plumbing: arguments, timing, machine facts, table and JSON output.

Every benchmark runs as ``python benchmarks/bench_NAME.py [--json PATH] [--quick]``, prints
a table and writes JSON. Compile time is measured apart from steady-state time (AOT
``lower().compile()``), and steady-state numbers are medians over repeated calls.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jaxloco.runtime import configure, quiet_library_logs, to_jsonable  # noqa: E402

configure()  # before any benchmark computes: the XLA options users run with


def parse_args(description: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--json", type=Path, default=None, help="write results to this file")
    parser.add_argument("--quick", action="store_true", help="small sizes, few repetitions")
    parser.add_argument(
        "--timeout", type=float, default=1800.0, help="watchdog: abort after this many seconds"
    )
    args = parser.parse_args()
    quiet_library_logs()
    return args


def pin_to_one_core() -> int | None:
    """Run this process (and every thread it starts afterwards, XLA's included) on one core,
    for per-core figures; call before JAX computes anything. Returns the core, or None
    where the platform cannot pin."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    core = max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return core


def interleaved(calls: dict, rounds: int) -> dict:
    """Time several callables round-robin, one timed call of each per round, so that a slow
    spell of the machine falls on all of them alike. Each timed call follows an untimed one
    of the same callable: steady-state times, not those of a cache another callable has just
    filled with its own data. ``calls``: name -> (fn, units of work per call). Returns per
    name the median seconds per unit over rounds, and per pair of names (``"a/b"``) the
    median over rounds of their per-round ratio."""
    samples = {name: [] for name in calls}
    for _ in range(rounds):
        for name, (fn, units) in calls.items():
            jax.block_until_ready(fn())
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            samples[name].append((time.perf_counter() - t0) / units)
    out = {name: statistics.median(s) for name, s in samples.items()}
    names = list(calls)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            out[f"{a}/{b}"] = statistics.median(
                x / y for x, y in zip(samples[a], samples[b], strict=True)
            )
    return out


def compile_seconds(jitted, *args) -> tuple[float, object]:
    """Trace + lower + compile time of a jitted function for these arguments."""
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return time.perf_counter() - t0, compiled


_COMPILE_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "xla_compile_s",
    "/jax/compilation_cache/compile_time_saved_sec": "cache_saved_s",
}


@contextlib.contextmanager
def compile_split():
    """Seconds JAX spent inside the block tracing, lowering and compiling with XLA (JAX's
    own monitoring events), and the compile seconds the persistent cache saved (> 0: a
    program came from the cache, so ``xla_compile_s`` is not a cold compile)."""
    tally = dict.fromkeys(_COMPILE_EVENTS.values(), 0.0)

    def listener(event: str, duration: float, **_) -> None:
        key = _COMPILE_EVENTS.get(event)
        if key is not None:
            tally[key] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield tally
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def time_calls(fn, *args, repeats: int, inner: int = 1, warmup: int = 2) -> dict:
    """Per-call wall time of ``fn(*args)`` (blocking on the result), in seconds.

    ``inner`` calls are timed together and divided (for microsecond-scale calls).
    """
    for _ in range(warmup):
        jax.block_until_ready(fn(*args))
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            out = fn(*args)
            jax.block_until_ready(out)
        samples.append((time.perf_counter() - t0) / inner)
    samples.sort()
    return {
        "median_s": statistics.median(samples),
        "p10_s": samples[max(0, len(samples) // 10)],
        "p90_s": samples[min(len(samples) - 1, (9 * len(samples)) // 10)],
        "repeats": repeats,
        "inner": inner,
    }


def machine() -> dict:
    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import mujoco

    return {
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def print_table(title: str, rows: list[dict], columns: list[tuple[str, str, str]]) -> dict:
    """Print rows as a table. ``columns``: (key, header, format spec). Returns the table as
    printed (``title``, ``headers``, ``rows`` of cells), for ``write_json``'s ``tables``."""
    cells = [
        [format(r.get(k, ""), f) if r.get(k) is not None else "-" for k, _, f in columns]
        for r in rows
    ]
    headers = [h for _, h, _ in columns]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(headers)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for c in cells:
        print("  ".join(v.ljust(w) for v, w in zip(c, widths, strict=True)))
    return {"title": title, "headers": headers, "rows": cells}


def target(name: str, measured: float, limit: float, unit: str, at_most: bool = True) -> dict:
    """One target of a benchmark: ``measured`` against ``limit`` (``at_most``: the measured
    value must not exceed it; else it must reach it). A measurement that is not a finite
    number (e.g. a level never reached) is recorded as ``None`` and misses the target."""
    finite = math.isfinite(measured)
    met = finite and (measured <= limit if at_most else measured >= limit)
    return {
        "name": name,
        "measured": float(measured) if finite else None,
        "target": f"{'<=' if at_most else '>='} {limit:g} {unit}".strip(),
        "met": bool(met),
    }


def print_targets(targets: list[dict]) -> None:
    for t in targets:
        value = "not reached" if t["measured"] is None else f"{t['measured']:.4g}"
        print(f"target: {t['name']}: {value} (required {t['target']}; met: {t['met']})")


def _commit() -> str:
    """The repository's commit (``+dirty`` with uncommitted changes), or '' outside git."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
        )
    except OSError:
        return ""
    if head.returncode != 0:
        return ""
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def write_json(
    path: Path | None,
    name: str,
    results: dict,
    tables: list[dict] | None = None,
    targets: list[dict] | None = None,
) -> None:
    """Write ``results`` with the machine, date, commit, the printed ``tables`` and the
    ``targets`` (:func:`target`); ``benchmarks/render_results.py`` makes RESULTS.md of it."""
    payload = {
        "benchmark": name,
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "commit": _commit(),
        "tables": tables or [],
        "targets": targets or [],
        **results,
    }
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_jsonable(payload), indent=2) + "\n")
    print(f"\nresults written to {path}")
