"""The ``jaxloco`` command: one entry point, one subcommand per experiment.

    jaxloco                       # list the experiments
    jaxloco phase-portrait        # run experiments/phase_portrait.py on its defaults
    jaxloco phase-portrait planner.h=0.95 --multirun policy=lookahead,nominal
    jaxloco phase-portrait --cfg job   # hydra's own flags work too

Each experiment is a hydra app in the repository's ``experiments/`` folder, installed as
the package ``jaxloco.experiments`` (or at ``$JAXLOCO_EXPERIMENTS_DIR``); everything after
the subcommand is passed to hydra unchanged.
"""

from __future__ import annotations

import importlib.util
import os
import runpy
import sys
from pathlib import Path

USAGE = "usage: jaxloco EXPERIMENT [hydra overrides and flags ...]"


def experiments_dir() -> Path:
    """The experiments' folder: ``$JAXLOCO_EXPERIMENTS_DIR`` if set, else the installed
    package ``jaxloco.experiments`` (the repository's ``experiments/``), else
    ``experiments/`` next to the package (a source tree not installed)."""
    env = os.environ.get("JAXLOCO_EXPERIMENTS_DIR")
    if env:
        path = Path(env)
    else:
        try:
            spec = importlib.util.find_spec("jaxloco.experiments")
        except ImportError:
            spec = None
        if spec is not None and spec.submodule_search_locations:
            path = Path(next(iter(spec.submodule_search_locations)))
        else:
            path = Path(__file__).resolve().parent.parent / "experiments"
    if not path.is_dir():
        raise SystemExit(
            f"jaxloco: no experiments folder at {path}: reinstall jaxloco, or set "
            "JAXLOCO_EXPERIMENTS_DIR to the repository's experiments/."
        )
    return path


def available(folder: Path) -> dict[str, Path]:
    """Subcommand name (dashes) -> experiment script."""
    return {
        p.stem.replace("_", "-"): p
        for p in sorted(folder.glob("*.py"))
        if not p.name.startswith("_")
    }


def _describe(path: Path) -> str:
    """First line of the script's docstring."""
    for line in path.read_text().splitlines():
        line = line.strip().strip('"').strip()
        if line:
            return line
    return ""


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    experiments = available(experiments_dir())
    if not argv or argv[0] in ("-h", "--help", "list"):
        print(USAGE)
        print("\nexperiments:")
        for name, path in experiments.items():
            print(f"  {name:24s} {_describe(path)}")
        print("\n`jaxloco EXPERIMENT --help` shows an experiment's config and hydra's flags.")
        return
    name = argv[0].replace("_", "-")
    if name not in experiments:
        raise SystemExit(
            f"jaxloco: unknown experiment {argv[0]!r}; choose from: {', '.join(experiments)}"
        )
    script = experiments[name]
    from jaxloco.runtime import configure  # noqa: PLC0415 (listing needs no JAX)

    configure()
    # Hydra reads sys.argv and names the job after the script.
    sys.argv = [str(script), *argv[1:]]
    sys.path.insert(0, str(script.parent))
    runpy.run_path(str(script), run_name="__main__")


if __name__ == "__main__":
    main()
