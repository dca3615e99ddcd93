"""Batched push-recovery sweeps: how robust is a walking controller, pushed in every
direction, with every magnitude, at every phase of the gait?

:class:`SweepSpec` says what to push (:mod:`.spec`); :func:`run_sweep` snapshots the
undisturbed walks (:mod:`.starts`), runs the pushes chunk by chunk on a physics backend
(:mod:`.backends`: MJX, or MuJoCo's C engine with the same vmapped controller), keeps a few
numbers per push (:mod:`.outcome`) and writes them to disk as it goes (:mod:`.store`);
:func:`write_report` turns a run directory into plots and tables (:mod:`.report`).
"""

from jaxloco.sweep.outcome import FIELDS
from jaxloco.sweep.report import paired_comparison, summarize, write_report
from jaxloco.sweep.run import BACKENDS, SweepResult, run_sweep
from jaxloco.sweep.spec import PushTable, SweepSpec, expand
from jaxloco.sweep.store import SweepStore

__all__ = [
    "BACKENDS",
    "FIELDS",
    "PushTable",
    "SweepResult",
    "SweepSpec",
    "SweepStore",
    "expand",
    "paired_comparison",
    "run_sweep",
    "summarize",
    "write_report",
]
