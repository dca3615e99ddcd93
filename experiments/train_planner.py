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

Writes to hydra's run directory: ``checkpoint/`` (weights, config, training state; load it
with ``jaxloco.learning.load_planner(path)``), ``learning_curve.png`` (return, survival,
spread and survival basin against iterations and wall time) and ``history.json``. With
``method=ppo`` the checkpoint holds the PPO networks (also loaded by ``load_planner``) and
the curve is the survival basin and Brax's episode reward against env steps and wall time;
``planner.*`` and ``starts.*`` apply to both methods.
"""

import logging
from dataclasses import dataclass, field
from pathlib import Path

import hydra

from jaxloco.app import RunConfig, launch, register, run_in_hydra
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
from jaxloco.learning.ppo import PPOConfig, save_ppo_checkpoint, train_ppo
from jaxloco.learning.training import params_fingerprint
from jaxloco.planner import PSPParams
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
    if cfg.method == "ppo":
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
    save_checkpoint(out_dir / "checkpoint", result.best_params, config, info, result.state)
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
