"""What the experiment apps in ``experiments/`` share: the fields of every run config and
the set-up around a run.

An experiment is a config dataclass deriving :class:`RunConfig`, registered with
:func:`register`, and a function ``run(cfg, out_dir) -> summary``; its hydra main calls
:func:`run_in_hydra`, and its script calls :func:`launch`::

    register("body_shaking", BodyShakingConfig)

    @hydra.main(version_base="1.3", config_path=None, config_name="body_shaking")
    def main(cfg) -> None:
        summary, out_dir = run_in_hydra(cfg, run)
        print(...)

    if __name__ == "__main__":
        launch(main)

(The ``hydra.main`` decorator stays in the script: hydra names the job after the file that
defines the decorated function.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from jaxloco.runtime import configure, enable_compilation_cache, quiet_jax_logs, watchdog


@dataclass
class RunConfig:
    """Fields every experiment's config has."""

    timeout_s: float = 3600.0
    """Watchdog (s): past it the run stops and dumps every thread's stack (XLA on CPU has
    been seen to hang in ``block_until_ready``)."""
    dpi: int = 130
    """Resolution of the figures written (dots per inch)."""


def register(name: str, node: type, group: str | None = None) -> None:
    """Make the config dataclass ``node`` hydra's config ``name`` (in config group
    ``group``: an option picked by ``group=name`` on the command line)."""
    ConfigStore.instance().store(name=name, node=node, group=group)


def run_in_hydra(cfg, run: Callable, as_object: bool = True) -> tuple[dict, Path]:
    """Inside a hydra main: quiet JAX's plug-in logs, turn on the compile cache, and call
    ``run(config, out_dir)`` under the watchdog (``cfg.timeout_s``), with hydra's run
    directory and the config as its dataclass (``as_object``) or as hydra's node. Returns
    the summary and the directory."""
    quiet_jax_logs()
    enable_compilation_cache()
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    config = OmegaConf.to_object(cfg) if as_object else cfg
    with watchdog(config.timeout_s, HydraConfig.get().job.name):
        summary = run(config, out_dir)
    return summary, out_dir


def launch(main: Callable[[], None]) -> None:
    """Run a hydra main as a script: jaxloco's XLA options first (before JAX computes)."""
    configure()
    main()
