"""Rebuild a push sweep's report (plots, tables) from its run directory.

    jaxloco sweep-report run_dir=outputs/2026-11-23/10-00-00

Writes ``summary.md``, ``summary.json`` and the plots into ``run_dir`` itself (hydra's own
run directory gets only its logs).
"""

from dataclasses import dataclass
from pathlib import Path

import hydra

from jaxloco.app import RunConfig, launch, register, run_in_hydra
from jaxloco.sweep import write_report


@dataclass
class SweepReportConfig(RunConfig):
    run_dir: str = ""
    """A push-sweep run directory (it holds ``manifest.json``)."""
    dpi: int = 120


register("sweep_report", SweepReportConfig)


def run(cfg: SweepReportConfig, out_dir: Path) -> dict:
    """The report of ``cfg.run_dir``, written there (``out_dir``: unused, hydra's logs)."""
    if not cfg.run_dir:
        raise ValueError("run_dir: give a push-sweep run directory (run_dir=PATH)")
    return write_report(cfg.run_dir, dpi=cfg.dpi)


@hydra.main(version_base="1.3", config_path=None, config_name="sweep_report")
def main(cfg) -> None:
    summary, _ = run_in_hydra(cfg, run)
    for name, v in summary["variants"].items():
        print(f"{name}: recovered {v['recovered']}/{v['pushes']} ({v['success_rate']:.0%})")
    print(f"report written to {Path(cfg.run_dir) / 'summary.md'}")


if __name__ == "__main__":
    launch(main)
