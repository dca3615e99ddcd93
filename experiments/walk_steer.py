"""Fig. 11: the robot walks while steering (12 steps at +18.8 deg, 5 straight, 12 at -18.8).

    jaxloco walk-steer                              # the paper's schedule
    jaxloco walk-steer 'segments=[[4,10.0]]' video=false
    jaxloco walk-steer gains_file=outputs/tune/tuned_gains.json   # tune-push's gains/gamma
    jaxloco walk-steer viewer=true                  # watch it in MuJoCo's viewer (a display)

The learned RL-PSP policy picks every footstep and its timing; the user gives only the
heading change per step. Simulated in MuJoCo at 1 kHz under the walking WBLC.
Writes ``walk_steer.png`` (top view of the path and footsteps; CoM states mapped into the
local frames), ``walk_steer.json`` and ``walk_steer.gif``.
"""

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

import hydra
import numpy as np
from matplotlib.figure import Figure
from omegaconf import OmegaConf

from jaxloco.app import (
    RunConfig,
    launch,
    register,
    robot_physics_schema,
    robot_setup,
    run_in_hydra,
)
from jaxloco.config import config_schema, to_params
from jaxloco.control.gains import apply_gains_file, apply_gait_file
from jaxloco.control.presets import walking_config
from jaxloco.learning import load_planner
from jaxloco.locomotion import GaitParams, make_walking_controller
from jaxloco.locomotion.walking import robot_planner
from jaxloco.planner import turn_schedule
from jaxloco.runtime import (
    write_json,
)
from jaxloco.sim.mjx_loop import PhysicsParams
from jaxloco.sim.push import Push
from jaxloco.sim.render import plot_top_view, render_gif, stance_footsteps
from jaxloco.sim.scenarios import local_com_states, simulate_walk
from jaxloco.sim.viewer import open_viewer, require_display

log = logging.getLogger(__name__)

GaitSchema = config_schema(GaitParams)
PhysicsSchema = config_schema(PhysicsParams)


@dataclass
class WalkSteerConfig(RunConfig):
    segments: list = field(default_factory=lambda: [[12, 18.8], [5, 0.0], [12, -18.8]])
    """[[number of steps, degrees per step], ...] (Fig. 11)."""
    pushes: list[Push] = field(default_factory=list)
    """Pushes on the pelvis during the walk, e.g.
    ``'pushes=[{magnitude:250,direction_deg:90,start:4.2,duration:0.1}]'``."""
    extra_steps: int = 2
    """Straight steps after the schedule before the run ends."""
    max_duration: float = 40.0
    robot: str = "valkyrie"
    """A shipped robot (``jaxloco.robots.ROBOTS``): valkyrie, g1 or apollo."""
    gait: GaitSchema = field(default_factory=GaitSchema)
    """Walking state machine (:class:`~jaxloco.locomotion.gait_params.GaitParams`), in the
    reference robot's (Valkyrie's) size: scaled to ``robot``'s (Froude scaling)."""
    physics: PhysicsSchema = field(default_factory=robot_physics_schema(PhysicsSchema))
    """Simulation settings (:class:`~jaxloco.sim.mjx_loop.PhysicsParams`); the torque limit
    and solver iterations default to the robot's (Valkyrie: the paper's 500 N m bound, 2
    and 4 iterations; the others: their own effort limits, MuJoCo's default solver)."""
    gains_file: str = ""
    """A tuned gains file (``jaxloco tune-push`` writes ``tuned_gains.json``): its WBLC gains
    and its gait section (``replan_gamma``, ``replan_threshold``) replace the defaults."""
    planner: str = ""
    """RL-PSP checkpoint folder (``jaxloco train-planner`` writes one); empty: the shipped one."""
    video: bool = True
    video_fps: int = 10
    viewer: bool = False
    """Watch the walk in MuJoCo's passive viewer as it runs, no faster than real time
    (slower where the controller and physics take longer than a timestep); needs a
    display, and says so where there is none. The video is still written."""
    viewer_fps: float = 60.0
    """Viewer redraws per simulated second."""
    timeout_s: float = 1800.0
    dpi: int = 130


register("walk_steer", WalkSteerConfig)


def run(cfg: WalkSteerConfig, out_dir: Path) -> dict:
    if cfg.viewer:
        require_display()  # before anything is built or compiled
    robot, model, gait = robot_setup(cfg.robot, to_params(GaitParams, cfg.gait))
    turns = turn_schedule([tuple(s) for s in cfg.segments])
    planner = robot_planner(robot, model, load_planner(cfg.planner) if cfg.planner else None)
    gait = apply_gait_file(gait, cfg.gains_file)
    config = apply_gains_file(walking_config(robot), cfg.gains_file)
    ctrl = make_walking_controller(model, config=config, gait=gait, planner=planner, robot=robot)
    total = len(turns) + cfg.extra_steps
    res = simulate_walk(
        model,
        ctrl,
        cfg.max_duration,
        turns=turns,
        pushes=tuple(cfg.pushes),
        max_steps=total,
        physics=to_params(PhysicsParams, cfg.physics),
        progress="walk-steer",
        watch=(lambda m, d: open_viewer(m, d, cfg.viewer_fps)) if cfg.viewer else None,
    )
    o, t = res.log.outputs, res.log.time
    heading = np.asarray(o.heading)
    summary = {
        "config": OmegaConf.to_container(OmegaConf.structured(cfg)),
        "fell": bool(res.fell),
        "steps_begun": res.steps_taken,
        "steps_commanded": int(total),
        "simulated_s": float(t[-1]),
        "max_commanded_heading_deg": float(np.rad2deg(np.max(np.cumsum(turns)))),
        "final_commanded_heading_deg": float(np.rad2deg(np.sum(turns))),
        "max_heading_deg": float(np.rad2deg(heading.max())),
        "final_heading_deg": float(np.rad2deg(heading[-1])),
        "distance_m": float(np.sum(np.linalg.norm(np.diff(o.com[:, :2], axis=0), axis=1))),
        "max_com_error_m": float(np.max(o.com_error)),
        "replans": int(o.replans[-1]),
        "failed_plans": int(o.failed_plans[-1]),
        "qp_relaxed_ticks": int(np.sum(o.relaxed)),
    }
    summary["pushes"] = [dataclasses.asdict(p) for p in cfg.pushes]
    summary["completed"] = (not res.fell) and res.steps_taken >= total
    log.info("walk-steer: %s", {k: v for k, v in summary.items() if k != "config"})

    fig = Figure(figsize=(12, 5.5), constrained_layout=True)
    ax_top, ax_x, ax_y = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.6, 1, 1]})
    _, side, steps = stance_footsteps(t, o.stance, o.feet)
    plot_top_view(ax_top, o.com[:, :2], footsteps=steps, stance=side, lw=1.2)
    ax_top.plot(o.com_ref[:, 0], o.com_ref[:, 1], "k--", lw=0.6, label="CoM reference")
    for push in cfg.pushes:
        k = int(np.argmax(t >= push.start))
        if t[-1] >= push.start:
            u = np.array(
                [np.cos(np.radians(push.direction_deg)), np.sin(np.radians(push.direction_deg))]
            )
            ax_top.annotate(
                f"{push.magnitude:.0f} N",
                xy=o.com[k, :2],
                xytext=o.com[k, :2] - 0.3 * u,
                arrowprops={"arrowstyle": "->", "color": "k"},
                fontsize=8,
            )
    ax_top.legend(fontsize=8)
    ax_top.set_title("(a) top view: CoM path and footholds (green left, red right)")
    local = local_com_states(res.log)
    walking = np.asarray(o.phase) == 1
    step_id = np.asarray(o.step)
    for k in np.unique(step_id[walking]):
        m = walking & (step_id == k)
        ax_x.plot(local[m, 0], local[m, 1], lw=0.8)
        ax_y.plot(local[m, 2], local[m, 3], lw=0.8)
    ax_x.set(xlabel="x (m)", ylabel="xd (m/s)", title="(b) sagittal, in each local frame")
    ax_y.set(xlabel="y (m)", ylabel="yd (m/s)", title="lateral, in each local frame")
    for ax in (ax_x, ax_y):
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"Walking while steering (Fig. 11): {res.steps_taken} steps, "
        f"heading {summary['final_heading_deg']:.0f} deg at the end, fell={res.fell}"
    )
    fig.savefig(out_dir / "walk_steer.png", dpi=cfg.dpi)
    if cfg.video:
        render_gif(
            model,
            res.log.qpos,
            out_dir / "walk_steer.gif",
            t,
            fps=cfg.video_fps,
            title="walk-steer",
        )
    write_json(out_dir / "walk_steer.json", summary)
    return summary


@hydra.main(version_base="1.3", config_path=None, config_name="walk_steer")
def main(cfg) -> None:
    s, out_dir = run_in_hydra(cfg, run)
    print(
        f"walk-steer: {s['steps_begun']}/{s['steps_commanded']} steps, fell={s['fell']}, "
        f"final heading {s['final_heading_deg']:.1f} deg, max CoM error "
        f"{s['max_com_error_m']:.3f} m; outputs in {out_dir}"
    )


if __name__ == "__main__":
    launch(main)
