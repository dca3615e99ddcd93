"""Batched push recovery (the main job): how strong a push the walking robot takes.

    jaxloco push-sweep                                # limit search (make run; ~10 min, 2 cores)
    jaxloco push-sweep search=fine                    # 16 directions x 9 phases, 0.1/0.2 s
    jaxloco push-sweep 'search.durations=[0.1,0.2]' search.rounds=5
    jaxloco push-sweep address=tcp://head:8786        # on a Dask cluster (shared run dir)
    jaxloco push-sweep task=grid 'sweep.magnitudes=[300,520,700]' 'sweep.phases=[0.2,0.5,0.8]'
    jaxloco push-sweep task=grid backend=mjx chunk_size=32   # MJX instead of MuJoCo C
    jaxloco push-sweep task=grid sweep.mode=random sweep.num_random=256 'sweep.seeds=[0,1]'
    jaxloco push-sweep workers=1                      # in this process (default: per core)
    jaxloco push-sweep hydra.run.dir=outputs/my_sweep # run again: resumes
    jaxloco push-sweep gains_file=outputs/tune/tuned_gains.json   # tuned gains and gamma
    jaxloco sweep-report run_dir=outputs/my_sweep     # rebuild a grid sweep's report

``task=limits`` (the default) searches, per direction, phase, push duration and replanning
setting, the largest impulse the controller recovers (bisection with noisy replicas,
:mod:`jaxloco.sweep.bisection`): ``summary.md``/``.json``, ``limits_polar.png``,
``limits_heatmap.png``. ``task=grid`` runs the pushes of ``sweep`` (every combination of
its lists): ``summary.md``/``.json``, ``success_polar.png``, ``success_vs_phase.png``.

Each push starts from a snapshot of the undisturbed walk at its gait phase; every chunk of
``chunk_size`` pushes is one batched call of the chosen physics backend with the same
jitted, vmapped walking controller (physics + WBLC + learned planner) and is written to
disk as soon as it is done.
"""

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import hydra
from omegaconf import OmegaConf

from jaxloco.app import (
    RunConfig,
    launch,
    register,
    robot_default,
    robot_force_qp_schema,
    robot_physics_schema,
    robot_setup,
    run_in_hydra,
)
from jaxloco.config import config_schema, to_params
from jaxloco.control.force_qp import ForceQPParams
from jaxloco.control.gains import apply_gains_file, apply_gait_file
from jaxloco.control.presets import CLOSED_LOOP_QP, walking_config
from jaxloco.locomotion import GaitParams
from jaxloco.robots import robot_by_name
from jaxloco.sim.mjx_loop import PhysicsParams
from jaxloco.sweep import SweepSpec, run_sweep, write_report
from jaxloco.sweep.limit_search import FINE_SEARCH, LimitSearch
from jaxloco.sweep.limits import run_limit_search
from jaxloco.sweep.limits_report import write_limits_report

log = logging.getLogger(__name__)

SweepSchema = config_schema(SweepSpec)
GaitSchema = config_schema(GaitParams)
PhysicsSchema = config_schema(PhysicsParams)
ForceQPSchema = config_schema(ForceQPParams, CLOSED_LOOP_QP)
SearchSchema = config_schema(LimitSearch)
FineSearchSchema = config_schema(LimitSearch, FINE_SEARCH)
# The search's bracket and fall height follow the robot (the defaults are Valkyrie's).
ROBOT_SEARCH = {
    "impulse_range": [0.0, robot_default("impulse_high")],
    "fall_height": robot_default("fall_height"),
}
TASKS = ("limits", "grid")


@dataclass
class PushSweepConfig(RunConfig):
    defaults: list[Any] = field(default_factory=lambda: ["_self_", {"search": "default"}])
    robot: str = "valkyrie"
    """A shipped robot (``jaxloco.robots.ROBOTS``): valkyrie, g1 or apollo."""
    task: str = "limits"
    """``limits``: the limit search (``search``); ``grid``: the pushes of ``sweep``."""
    search: Any = None
    """The limit search (:class:`jaxloco.sweep.limit_search.LimitSearch`); ``search=fine`` picks
    the finer preset (``limit_search.FINE_SEARCH``)."""
    sweep: SweepSchema = field(
        default_factory=lambda: SweepSchema(fall_height=robot_default("fall_height"))
    )
    """The pushes of ``task=grid``."""
    gait: GaitSchema = field(default_factory=GaitSchema)
    """Walking state machine (:class:`~jaxloco.locomotion.gait_params.GaitParams`), in the
    reference robot's (Valkyrie's) size: scaled to ``robot``'s (Froude scaling)."""
    physics: PhysicsSchema = field(default_factory=robot_physics_schema(PhysicsSchema))
    """Simulation settings; the torque limit and solver iterations default to the robot's
    (Valkyrie: the paper's 500 N m bound, 2 and 4 iterations; the others: their own effort
    limits, MuJoCo's default solver)."""
    force_qp: ForceQPSchema = field(default_factory=robot_force_qp_schema(ForceQPSchema))
    """The walking WBLC's contact-force QP (defaults: the robot's ``presets.walking_force_qp``:
    ``CLOSED_LOOP_QP``, or ``CLOSED_LOOP_TORQUE_QP`` for a robot that keeps torque rows,
    its friction pyramids the robot's), e.g. ``force_qp.iterations=200``."""
    backend: str = "c"
    """``c`` (MuJoCo C batch, the CPU default: measured faster here) or ``mjx`` (grid only)."""
    chunk_size: int = 16
    nthread: int = 0
    """Threads of the C backend (0: all cores); with several workers, each uses one."""
    workers: int = 0
    """Local Dask worker processes running chunks side by side, each pinned to its own
    core (C backend; 0: one per core when there is enough work, at least 50 simulated
    robot-seconds each, else 1: in this process). The same results for any number."""
    address: str = ""
    """A Dask scheduler's address (``tcp://host:8786``): run the chunks on that cluster
    instead; its workers must see the run directory (a shared file system)."""
    max_chunks: int = 0
    """Stop after this many new chunks (0: run all); run again to go on."""
    pinv_rtol: float = 1e-2
    """The walking WBLC's rank threshold (``WBLCConfig.pinv_rtol``)."""
    whiten_tasks: bool = True
    """Threshold in whitened task rows (``WBLCConfig.whiten_tasks``)."""
    hierarchy_inverse: str = ""
    """``damped`` or ``truncated`` at every level (``WBLCConfig.hierarchy_inverse``); empty:
    the walking preset's (``presets.WALKING_INVERSES``)."""
    torque_pinv_rtol: float = 1e-8
    """The rank threshold of Eq. 19's torque solve (``WBLCConfig.torque_pinv_rtol``)."""
    com_acc_limit: float = float("inf")
    """Bound on the norm of the CoM task's horizontal acceleration command, m/s^2
    (``WBLCConfig.com_acc_limit``; inf: unbounded, the paper's)."""
    torque_limits_in_qp: Optional[bool] = None  # noqa: UP045 (OmegaConf needs typing.Optional)
    """Keep the legs' torques within the model's effort limits in the force QP
    (``WBLCConfig.torque_limits_in_qp``); pair with ``physics.torque_limit=model``. None:
    the robot's default (Valkyrie: off; the others: on)."""
    whole_body_limits: Optional[bool] = None  # noqa: UP045
    """Keep every joint's torque within its effort limit in the controller's last stage
    (``WBLCConfig.whole_body_limits``), the lowest tasks giving way. None: the robot's
    default."""
    planner: str = ""
    """A step-policy checkpoint folder (``jaxloco train-planner`` writes one); empty: the
    shipped default. Use a new run directory for another policy."""
    gains_file: str = ""
    """A tuned gains file (``tune-gains``, ``tune-push``): its WBLC gains and its gait
    section (e.g. ``replan_gamma``) replace the defaults. Use a new run directory for it."""
    timeout_s: float = 3600.0
    """Watchdog: the run fails loudly (stack dump, exit 1) past this."""
    dpi: int = 120


register("push_sweep", PushSweepConfig)
register("default", SearchSchema(**ROBOT_SEARCH), group="search")
register("fine", FineSearchSchema(**ROBOT_SEARCH), group="search")


def controller_settings(cfg) -> dict:
    """The walking controller under test: robot, gait (scaled to the robot), physics and
    WBLC config (tuned gains applied)."""
    robot, _, gait = robot_setup(cfg.robot, to_params(GaitParams, cfg.gait))
    return {
        "robot": robot.name,
        "planner": cfg.planner or None,
        "gait": apply_gait_file(gait, cfg.gains_file),
        "physics": to_params(PhysicsParams, cfg.physics),
        "wblc": apply_gains_file(
            walking_config(
                robot,
                pinv_rtol=cfg.pinv_rtol,
                whiten_tasks=cfg.whiten_tasks,
                torque_pinv_rtol=cfg.torque_pinv_rtol,
                com_acc_limit=cfg.com_acc_limit,
                torque_limits_in_qp=cfg.torque_limits_in_qp,
                whole_body_limits=cfg.whole_body_limits,
                force_qp=to_params(ForceQPParams, cfg.force_qp),
                **({"hierarchy_inverse": cfg.hierarchy_inverse} if cfg.hierarchy_inverse else {}),
            ),
            cfg.gains_file,
        ),
    }


def _robot_mass(name: str) -> float | None:
    """The robot's mass (kg) for the report's velocity terms; None for Valkyrie, whose
    report stays in the paper's terms (52 N s)."""
    robot = robot_by_name(name)
    return None if robot.length_scale == 1.0 else float(robot.load().body_subtreemass[0])


def run(cfg, out_dir: Path):
    """The limit search or the grid sweep into ``out_dir`` (resumed if it holds one), and
    its report."""
    if cfg.task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}; got {cfg.task!r}")
    common = dict(
        backend=cfg.backend,
        chunk_size=cfg.chunk_size,
        workers=cfg.workers,
        address=cfg.address or None,
        config=OmegaConf.to_container(cfg, resolve=True),
        **controller_settings(cfg),
    )
    if cfg.task == "limits":
        if cfg.backend != "c":
            raise ValueError("task=limits runs on the C backend; use backend=c")
        result = run_limit_search(to_params(LimitSearch, cfg.search), out_dir, **common)
        report = write_limits_report(
            result,
            out_dir,
            dpi=cfg.dpi,
            mass=_robot_mass(cfg.robot),
            torque_limit=to_params(PhysicsParams, cfg.physics).torque_limit,
        )
        return {"task": "limits", "report": report}
    result = run_sweep(
        to_params(SweepSpec, cfg.sweep),
        out_dir,
        nthread=cfg.nthread or None,
        max_chunks=cfg.max_chunks or None,
        **common,
    )
    return {"task": "grid", "report": write_report(out_dir, dpi=cfg.dpi), "result": result}


@hydra.main(version_base="1.3", config_path=None, config_name="push_sweep")
def main(cfg) -> None:
    out, out_dir = run_in_hydra(cfg, run, as_object=False)
    summary = out["report"]
    if out["task"] == "limits":
        for name, v in summary["variants"].items():
            print(
                f"{name}: largest recovered impulse median {v['median_limit_Ns']:g} N s "
                f"(min {v['min_limit_Ns']:g}, max {v['max_limit_Ns']:g}); "
                f"{v['cells_at_least_paper']}/{v['cells']} cells >= "
                f"{summary['paper_impulse_Ns']:g} N s (the paper's push)"
            )
        print(f"report: {out_dir / 'summary.md'} (plots: limits_polar.png, limits_heatmap.png)")
        return
    result = out["result"]
    for name, v in summary["variants"].items():
        print(f"{name}: recovered {v['recovered']}/{v['pushes']} ({v['success_rate']:.0%})")
    done = int(result.complete.sum())
    if done < len(result.table):
        print(f"{done}/{len(result.table)} pushes done; run the same command again to go on")
    print(f"report: {out_dir / 'summary.md'} (plots: success_polar.png, success_vs_phase.png)")


if __name__ == "__main__":
    launch(main)
