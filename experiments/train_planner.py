"""Train the RL-PSP step policy (Algorithm 1, batched; then refined through the
differentiable planner) and save it with its learning curve.

    jaxloco train-planner              # 50 Algorithm 1 iterations (FAST), then refinement
    # Algorithm 1 alone, as the paper (the FAST preset's full budget)
    jaxloco train-planner refine.iterations=0 actor_critic.max_iterations=600
    jaxloco train-planner actor_critic.max_iterations=400 actor_critic.seed=3
    # no Algorithm 1: refinement from the initial weights (the value stays untrained)
    jaxloco train-planner actor_critic.max_iterations=0 refine.iterations=300
    jaxloco train-planner hydra.run.dir=runs/planner   # choose the output folder
    jaxloco train-planner resume_from=runs/planner/checkpoint
    jaxloco train-planner method=ppo                   # Brax's PPO baseline instead
    jaxloco train-planner method=ppo ppo.num_timesteps=8000000 ppo.seed=1
    jaxloco train-planner robot=g1                     # a policy for the Unitree G1's size

Writes to hydra's run directory: ``checkpoint/`` (weights, config, training state; load it
with ``jaxloco.learning.load_planner(path)``), ``learning_curve.png`` (return, survival,
spread and survival basin against iterations and wall time) and ``history.json``. With
``method=ppo`` the checkpoint holds the PPO networks (also loaded by ``load_planner``) and
the curve is the survival basin and Brax's episode reward against env steps and wall time;
``planner.*`` and ``starts.*`` apply to both methods.

``robot=g1`` (any shipped robot other than Valkyrie): the LIPM is the same at every size
once lengths scale by the robot's size ``L`` and times by ``sqrt(L)`` (Froude scaling,
:mod:`jaxloco.planner.scaling`), so training runs in the reference size's units and the
checkpoint is a scaled one: ``checkpoint/scaled.json`` (the robot's scale) wrapping
``checkpoint/reference/``. Its survival basin is also measured at the robot's size, on the
robot's apex-state box, on a draw independent of training's (``robot_basin``).
"""

import logging
from dataclasses import dataclass, field
from pathlib import Path

import hydra
import jax

from jaxloco.app import RunConfig, launch, register, robot_setup, run_in_hydra
from jaxloco.config import config_schema, to_params
from jaxloco.learning import (
    WARM_START,
    ActorCriticConfig,
    EpisodeTurns,
    EvalConfig,
    RBFGrid,
    RefineConfig,
    StartStates,
    TrainConfig,
    save_checkpoint,
    train,
)
from jaxloco.learning.checkpoint import load_checkpoint_config, load_train_state
from jaxloco.learning.evaluation import survival_basin
from jaxloco.learning.loading import load_planner, save_scaled_checkpoint
from jaxloco.learning.ppo import PPOConfig, save_ppo_checkpoint, train_ppo
from jaxloco.learning.scaled import scale_box
from jaxloco.learning.training import params_fingerprint
from jaxloco.planner import PSPParams
from jaxloco.robots import robot_scale
from jaxloco.runtime import write_json
from jaxloco.viz.learning import plot_learning_curve, plot_ppo_curve

log = logging.getLogger(__name__)
ActorCriticSchema = config_schema(ActorCriticConfig, WARM_START)
GridSchema = config_schema(RBFGrid)
StartsSchema = config_schema(StartStates)
PlannerSchema = config_schema(PSPParams)
EvalSchema = config_schema(EvalConfig)
TurnsSchema = config_schema(EpisodeTurns)
RefineSchema = config_schema(RefineConfig)
PPOSchema = config_schema(PPOConfig)
METHODS = ("rl_psp", "ppo")


@dataclass
class TrainPlannerConfig(RunConfig):
    robot: str = "valkyrie"
    """The robot the policy is for (``jaxloco.robots.ROBOTS``); see the module doc."""
    method: str = "rl_psp"
    """``rl_psp``: Algorithm 1, then the refinement (the paper's learner); ``ppo``: Brax's
    PPO on the same step task (a baseline; its settings are ``ppo.*``)."""
    actor_critic: ActorCriticSchema = field(default_factory=ActorCriticSchema)
    grid: GridSchema = field(default_factory=GridSchema)
    starts: StartsSchema = field(default_factory=StartsSchema)
    planner: PlannerSchema = field(default_factory=PlannerSchema)
    evaluation: EvalSchema = field(default_factory=EvalSchema)
    turns: TurnsSchema = field(default_factory=TurnsSchema)
    """Steering during training episodes (default: straight, as the paper). The
    :data:`~jaxloco.learning.training.STEERING` preset is ``turns.max_deg=20
    actor_critic.max_iterations=800``."""
    refine: RefineSchema = field(default_factory=RefineSchema)
    """Refinement of the mean policy through the differentiable planner after Algorithm 1
    (``refine.iterations=0``: Algorithm 1 alone, as the paper)."""
    ppo: PPOSchema = field(default_factory=PPOSchema)
    """Brax PPO's settings (``method=ppo`` only)."""
    resume_from: str = ""
    """A checkpoint folder to continue training from (its config is used; RL-PSP only)."""
    progress: bool = True
    dpi: int = 130


register("train_planner", TrainPlannerConfig)


def build_config(cfg: TrainPlannerConfig) -> TrainConfig:
    return TrainConfig(
        actor_critic=to_params(ActorCriticConfig, cfg.actor_critic),
        grid=to_params(RBFGrid, cfg.grid),
        starts=to_params(StartStates, cfg.starts),
        planner=to_params(PSPParams, cfg.planner),
        evaluation=to_params(EvalConfig, cfg.evaluation),
        turns=to_params(EpisodeTurns, cfg.turns),
        refine=to_params(RefineConfig, cfg.refine),
    )


def run(cfg: TrainPlannerConfig, out_dir: Path) -> dict:
    if cfg.method not in METHODS:
        raise ValueError(f"method must be one of {list(METHODS)}; got {cfg.method!r}")
    robot, model, _ = robot_setup(cfg.robot)  # a bad name fails before training
    scale = robot_scale(robot, model)
    if cfg.method == "ppo":
        if scale.length != 1.0:
            raise ValueError(
                f"robot: method=ppo writes reference-size checkpoints only; got {cfg.robot!r} "
                "(the walking controller scales any planner to its robot: robot_planner)"
            )
        return run_ppo(cfg, out_dir)
    state = None
    if cfg.resume_from:
        config, _ = load_checkpoint_config(cfg.resume_from)
        state = load_train_state(cfg.resume_from, config)
        log.info("resuming from %s at iteration %d", cfg.resume_from, int(state.iteration))
    else:
        config = build_config(cfg)
    result = train(config, progress=cfg.progress, state=state)
    info = {
        "iteration": int(result.state.iteration),
        "stop_reason": result.stop_reason,
        "best_basin": result.best_basin,
        "best_steering_basin": result.best_steering_basin,
        "actor_critic_basin": result.actor_critic_basin,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.train_seconds,
        "eval_seconds": result.eval_seconds,
        "fingerprint": params_fingerprint(result.best_params),
    }
    ref = result.refinement
    if ref is not None:
        info["refine"] = {
            "iterations": len(ref.history),
            "compile_seconds": ref.compile_seconds,
            "train_seconds": ref.train_seconds,
            "eval_seconds": ref.eval_seconds,
            "start": ref.start,
            "best": ref.best,
        }
    if scale.length == 1.0:
        save_checkpoint(out_dir / "checkpoint", result.best_params, config, info, result.state)
    else:
        reference = out_dir / "checkpoint" / "reference"
        save_checkpoint(reference, result.best_params, config, info, result.state)
        save_scaled_checkpoint(out_dir / "checkpoint", reference, scale, robot.name)
        info["robot"] = robot_basin(out_dir / "checkpoint", config, robot.name, scale)
        log.info("at %s's size: %s", robot.name, info["robot"])
    write_json(out_dir / "history.json", {"info": info, "history": result.history})
    fig = plot_learning_curve(result.history, title="RL-PSP training")
    fig.savefig(out_dir / "learning_curve.png", dpi=cfg.dpi)
    log.info(
        "Algorithm 1 stopped after %d iterations (%s); survival basin %s; compile %.1f s, "
        "training %.1f s, evaluation %.1f s",
        info["iteration"],
        result.stop_reason,
        _fmt(result.actor_critic_basin),
        result.compile_seconds,
        result.train_seconds,
        result.eval_seconds,
    )
    if ref is not None:
        log.info(
            "refinement: %d steps; compile %.1f s, steps %.1f s, evaluation %.1f s",
            len(ref.history),
            ref.compile_seconds,
            ref.train_seconds,
            ref.eval_seconds,
        )
    steering = result.best_steering_basin
    log.info(
        "kept survival basin %s%s",
        _fmt(result.best_basin),
        f", steering basin {_fmt(steering)}" if steering is not None else "",
    )
    return info


ROBOT_BASIN_SEED = 777
"""The draw of the robot-size basin: independent of training's and evaluation's."""


def robot_basin(path, config: TrainConfig, name: str, scale) -> dict:
    """The survival basin of the scaled checkpoint at ``path`` on the robot's apex-state box
    (``config.starts``' box in the robot's units), 65,536 states of an independent draw."""
    planner = load_planner(path)
    box = scale_box(config.starts, scale)
    basin, _, _ = survival_basin(
        planner.policy,
        planner.psp,
        jax.random.PRNGKey(ROBOT_BASIN_SEED),
        65536,
        config.evaluation.num_steps,
        box,
    )
    return {
        "name": name,
        "length_scale": scale.length,
        "box_low": list(box.box_low),
        "box_high": list(box.box_high),
        "basin": float(basin),
        "seed": ROBOT_BASIN_SEED,
    }


def run_ppo(cfg: TrainPlannerConfig, out_dir: Path) -> dict:
    if cfg.resume_from:
        raise ValueError("resume_from: resuming is for method=rl_psp; PPO runs start afresh")
    config = to_params(PPOConfig, cfg.ppo)
    result = train_ppo(
        config,
        to_params(PSPParams, cfg.planner),
        to_params(StartStates, cfg.starts),
        progress=cfg.progress,
    )
    info = {
        "method": "ppo",
        "best_basin": result.best_basin,
        "train_seconds": result.train_seconds,
        "env_steps": result.history[-1]["env_steps"],
    }
    save_ppo_checkpoint(out_dir / "checkpoint", result.planner, info)
    write_json(out_dir / "history.json", {"info": info, "history": result.history})
    fig = plot_ppo_curve(result.history, title="PPO (Brax) on the step task")
    fig.savefig(out_dir / "learning_curve.png", dpi=cfg.dpi)
    log.info(
        "PPO: %d env steps in %.1f s (compile and evaluations included); kept survival basin %s",
        info["env_steps"],
        result.train_seconds,
        _fmt(result.best_basin),
    )
    return info


def _fmt(basin):
    return f"{basin:.3f}" if basin is not None else "not evaluated"


@hydra.main(version_base="1.3", config_path=None, config_name="train_planner")
def main(cfg) -> None:
    _, out_dir = run_in_hydra(cfg, run)
    print(f"checkpoint and learning curve written to {out_dir}")


if __name__ == "__main__":
    launch(main)
