"""Compare limit searches per direction (e.g. the same search at two torque bounds).

    jaxloco limits-compare 'runs=[outputs/bound_500,outputs/model_limits]' \
        'labels=["500 N m",model]' hydra.run.dir=outputs/limits_compared

Each run directory holds a limit search's ``summary.json`` (``jaxloco push-sweep``). Writes
``comparison.md`` (per direction, the worst phase's limit and the median over phases, per
run), ``comparison.json`` and ``comparison_polar.png`` to hydra's run directory.
"""

import json
from dataclasses import dataclass, field
from pathlib import Path

import hydra

from jaxloco.app import RunConfig, launch, register, run_in_hydra
from jaxloco.sweep.limits_report import write_limits_comparison


@dataclass
class LimitsCompareConfig(RunConfig):
    runs: list[str] = field(default_factory=list)
    """Limit-search run directories, 2 or more (each holds a ``summary.json``)."""
    labels: list[str] = field(default_factory=list)
    """One distinct label per run, in the same order; empty: the folders' names."""
    dpi: int = 120


register("limits_compare", LimitsCompareConfig)


def run(cfg: LimitsCompareConfig, out_dir: Path) -> dict:
    """The comparison of ``cfg.runs``' summaries, written to ``out_dir``."""
    if len(cfg.runs) < 2:
        raise ValueError(f"runs: needs at least two limit-search run directories; got {cfg.runs}")
    labels = list(cfg.labels) or [Path(d).name for d in cfg.runs]
    if len(labels) != len(cfg.runs) or len(set(labels)) != len(labels):
        raise ValueError(f"labels: one distinct label per run ({len(cfg.runs)} runs); got {labels}")
    summaries = {}
    for label, run_dir in zip(labels, cfg.runs, strict=True):
        path = Path(run_dir) / "summary.json"
        if not path.is_file():
            raise ValueError(f"runs: no limit search summary at {path}")
        summaries[label] = json.loads(path.read_text())
    return write_limits_comparison(summaries, out_dir, dpi=cfg.dpi)


@hydra.main(version_base="1.3", config_path=None, config_name="limits_compare")
def main(cfg) -> None:
    comparison, out_dir = run_in_hydra(cfg, run)
    for name, variant in comparison["variants"].items():
        medians = ", ".join(f"{lb}: {m:g}" for lb, m in variant["median_limit_Ns"].items())
        print(f"{name}: median limit (N s) {medians}")
    print(f"comparison written to {out_dir / 'comparison.md'}")


if __name__ == "__main__":
    launch(main)
