"""Batched push-recovery sweeps: how robust is a walking controller, pushed in every
direction, with every magnitude, at every phase of the gait?

:class:`SweepSpec` says what to push (:mod:`.spec`); :func:`run_sweep` runs its pushes as a
:class:`SweepJob` (:mod:`.job`) chunk by chunk: each chunk through the one
:class:`ChunkRunner` (:mod:`.chunks`), which starts every push from a snapshot of the
undisturbed walk (:mod:`.starts`) on a physics backend (:mod:`.backends`: MJX, or MuJoCo's
C engine with the same vmapped controller), keeps a few numbers per push (:mod:`.outcome`)
and writes them to disk as it goes (:mod:`.store`). Chunks run in this process
(:mod:`.executors`) or as tasks on Dask distributed (:mod:`.cluster`).
:func:`write_report` turns a run directory into plots and tables (:mod:`.report`).
:func:`run_limit_search` finds the largest recovered impulse per direction and phase by
bisection, one sweep per round (:mod:`.limits`; the search's settings :mod:`.limit_search`,
its bisection :mod:`.bisection`, its result :mod:`.limit_result`, reported by
:mod:`.limits_report`).
"""

from jaxloco.sweep.chunks import ChunkReport, ChunkRunner
from jaxloco.sweep.job import BACKENDS, SweepJob
from jaxloco.sweep.limit_result import LimitResult
from jaxloco.sweep.limit_search import FINE_SEARCH, LimitSearch
from jaxloco.sweep.limits import run_limit_search
from jaxloco.sweep.limits_report import write_limits_report
from jaxloco.sweep.outcome import FIELDS
from jaxloco.sweep.report import paired_comparison, summarize, write_report
from jaxloco.sweep.run import SweepResult, make_job, run_sweep, run_table
from jaxloco.sweep.spec import PushTable, SweepSpec, expand
from jaxloco.sweep.store import SweepStore

__all__ = [
    "BACKENDS",
    "FIELDS",
    "FINE_SEARCH",
    "ChunkReport",
    "ChunkRunner",
    "LimitResult",
    "LimitSearch",
    "PushTable",
    "SweepJob",
    "SweepResult",
    "SweepSpec",
    "SweepStore",
    "expand",
    "make_job",
    "paired_comparison",
    "run_limit_search",
    "run_sweep",
    "run_table",
    "summarize",
    "write_limits_report",
    "write_report",
]
