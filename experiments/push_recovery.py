"""Fig. 12-13: pushes on the pelvis while walking, with and without replanning (Eq. 33-34).

    jaxloco push-recovery                                   # 520 N x 0.1 s, 8 directions
    jaxloco push-recovery 'directions_deg=[0,90]' magnitude=400 videos=false
    jaxloco push-recovery gains_file=outputs/tune/tuned_gains.json  # tune-push's gains/gamma

Each push starts at ``push_time`` (mid single support on the default gait). Every direction
runs twice, with the learned planner replanning after the push and with replanning off, next
to one undisturbed walk. ``direction_deg`` is where the force points (0 = forward, i.e. a
push from behind; 90 = to the robot's left). A push is recovered when the robot is still
up at the end and has begun ``steps_after`` more steps after the push.
Writes ``push_recovery.png`` (phase plots disturbed vs undisturbed, top views with the
replanned footsteps), ``push_recovery.json``/``.md`` (outcomes table, replanning time of
15 steps) and one GIF per direction.
"""

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import hydra
import jax
import jax.numpy as jnp
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
from jaxloco.planner import plan_steps
from jaxloco.runtime import (
    write_json,
)
from jaxloco.sim.mjx_loop import PhysicsParams
from jaxloco.sim.mujoco_c import PackedController
from jaxloco.sim.push import Push
from jaxloco.sim.render import plot_top_view, render_gif, stance_footsteps
from jaxloco.sim.scenarios import local_com_states, simulate_walk

log = logging.getLogger(__name__)

GaitSchema = config_schema(GaitParams)
PhysicsSchema = config_schema(PhysicsParams)


@dataclass
class PushRecoveryConfig(RunConfig):
    directions_deg: list = field(default_factory=lambda: [0, 45, 90, 135, 180, 225, 270, 315])
    magnitude: float = 520.0
    push_duration: float = 0.1
    push_time: float = 4.2
    """Push start (s); 4.2 s is mid single support on the default gait (measured)."""
    duration: float = 8.0
    """Simulated seconds per run."""
    steps_after: int = 3
    """Steps that must begin after the push for it to count as recovered."""
    compare_no_replan: bool = True
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
    videos: bool = True
    video_fps: int = 10
    timeout_s: float = 3600.0
    dpi: int = 120


register("push_recovery", PushRecoveryConfig)


def replanning_time_15_steps(planner, repeats: int = 200) -> dict:
    """Wall time of planning 15 steps with the learned policy (jitted, from a pushed apex
    state), as the paper reports (< 1 ms)."""
    fn = jax.jit(lambda s: plan_steps(s, planner.policy, planner.psp, 15, unroll=True))
    start = jnp.asarray([0.05, 0.39, 0.33], jnp.float32)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(start))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(start))
        times.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * float(np.median(times)), "compile_s": compile_s}


def _outcome(res, push_time, steps_after):
    o = res.log.outputs
    t = res.log.time
    after = t >= push_time
    step_at_push = int(o.step[np.argmax(after)]) if after.any() else 0
    steps_after_push = int(o.step[-1]) - step_at_push
    recovered = (not res.fell) and steps_after_push >= steps_after
    return {
        "recovered": bool(recovered),
        "fell": bool(res.fell),
        "fall_time_s": res.fall_time,
        "steps_after_push": steps_after_push,
        "replans": int(o.replans[-1]),
        "failed_plans": int(o.failed_plans[-1]),
        "max_com_error_m": float(np.max(o.com_error[after])) if after.any() else 0.0,
        "qp_relaxed_ticks": int(np.sum(o.relaxed[after])),
        "peak_torque_norm_Nm": float(np.max(o.torque_norm)),
    }


def run(cfg: PushRecoveryConfig, out_dir: Path) -> dict:
    robot, model, gait = robot_setup(cfg.robot, to_params(GaitParams, cfg.gait))
    physics = to_params(PhysicsParams, cfg.physics)
    gait = apply_gait_file(gait, cfg.gains_file)
    config = apply_gains_file(walking_config(robot), cfg.gains_file)
    variants = {"replan": gait}
    if cfg.compare_no_replan:
        variants["no_replan"] = dataclasses.replace(gait, replan=False)
    planner = robot_planner(robot, model, load_planner(cfg.planner) if cfg.planner else None)
    ctrls = {
        k: make_walking_controller(model, config=config, gait=g, planner=planner, robot=robot)
        for k, g in variants.items()
    }
    steps = {k: PackedController(c.step) for k, c in ctrls.items()}  # one compile per variant
    results, runs = {}, {}
    base = simulate_walk(
        model,
        ctrls["replan"],
        cfg.duration,
        physics=physics,
        progress="undisturbed",
        step=steps["replan"],
    )
    for name, ctrl in ctrls.items():
        for direction in cfg.directions_deg:
            push = Push(cfg.magnitude, float(direction), cfg.push_time, cfg.push_duration)
            res = simulate_walk(
                model,
                ctrl,
                cfg.duration,
                pushes=(push,),
                physics=physics,
                progress=f"{name} {direction} deg",
                step=steps[name],
            )
            runs[name, direction] = res
            results.setdefault(name, {})[str(direction)] = _outcome(
                res, cfg.push_time, cfg.steps_after
            )
            log.info("%s %s deg: %s", name, direction, results[name][str(direction)])
    timing = replanning_time_15_steps(planner)

    summary = {
        "config": OmegaConf.to_container(OmegaConf.structured(cfg)),
        "impulse_Ns": cfg.magnitude * cfg.push_duration,
        "undisturbed_fell": bool(base.fell),
        "results": results,
        "recovered": {k: sum(v["recovered"] for v in r.values()) for k, r in results.items()},
        "directions": len(cfg.directions_deg),
        "replanning_15_steps": timing,
    }
    write_json(out_dir / "push_recovery.json", summary)
    (out_dir / "push_recovery.md").write_text(_markdown(summary))

    # Figure: lateral and sagittal phase plots (replanning on), top views.
    n = len(cfg.directions_deg)
    fig = Figure(figsize=(3.2 * n, 9), constrained_layout=True)
    axes = fig.subplots(3, n, squeeze=False)
    base_local = local_com_states(base.log)
    for j, direction in enumerate(cfg.directions_deg):
        res = runs["replan", direction]
        local = local_com_states(res.log)
        t = res.log.time
        window = (t >= cfg.push_time - 0.5) & (t <= cfg.push_time + 2.5)
        bw = (base.log.time >= cfg.push_time - 0.5) & (base.log.time <= cfg.push_time + 2.5)
        ax_y, ax_x, ax_top = axes[0, j], axes[1, j], axes[2, j]
        ax_y.plot(base_local[bw, 2], base_local[bw, 3], "0.6", lw=0.8, label="undisturbed")
        ax_y.plot(local[window, 2], local[window, 3], lw=0.8, label="pushed")
        ax_x.plot(base_local[bw, 0], base_local[bw, 1], "0.6", lw=0.8)
        ax_x.plot(local[window, 0], local[window, 1], lw=0.8)
        r = results["replan"][str(direction)]
        ax_y.set_title(f"{direction} deg: {'recovered' if r['recovered'] else 'fell'}", fontsize=9)
        ax_y.set(xlabel="y (m)", ylabel="yd (m/s)")
        ax_x.set(xlabel="x (m)", ylabel="xd (m/s)")
        o = res.log.outputs
        _, side, steps = stance_footsteps(t, o.stance, o.feet)
        bo = base.log.outputs
        plot_top_view(ax_top, bo.com[:, :2], label="undisturbed", color="0.6", lw=0.8)
        plot_top_view(ax_top, o.com[:, :2], footsteps=steps, stance=side, label="pushed", lw=1)
        k = int(np.argmax(t >= cfg.push_time))
        ax_top.annotate(
            "",
            xy=o.com[k, :2],
            xytext=o.com[k, :2]
            - 0.25 * np.array([np.cos(np.radians(direction)), np.sin(np.radians(direction))]),
            arrowprops={"arrowstyle": "->", "color": "k"},
        )
        for ax in (ax_y, ax_x):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(
        f"Push recovery while walking: {cfg.magnitude:.0f} N x {cfg.push_duration} s on the "
        f"pelvis at t = {cfg.push_time} s (replanning on; recovered "
        f"{summary['recovered']['replan']}/{n})"
    )
    fig.savefig(out_dir / "push_recovery.png", dpi=cfg.dpi)
    if cfg.videos:
        for direction in cfg.directions_deg:
            res = runs["replan", direction]
            render_gif(
                model,
                res.log.qpos,
                out_dir / f"push_{direction}deg.gif",
                res.log.time,
                fps=cfg.video_fps,
                title=f"push {direction} deg",
            )
    return summary


def _markdown(summary: dict) -> str:
    lines = [
        f"Push {summary['impulse_Ns']:.0f} N s on the pelvis while walking",
        "",
        "| variant | direction (deg) | recovered | fall time (s) | steps after | replans "
        "| failed plans | max CoM error (m) | QP relaxed ticks |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in summary["results"].items():
        for direction, r in rows.items():
            fall = "" if r["fall_time_s"] is None else f"{r['fall_time_s']:.2f}"
            lines.append(
                f"| {name} | {direction} | {r['recovered']} | {fall} | {r['steps_after_push']} "
                f"| {r['replans']} | {r['failed_plans']} | {r['max_com_error_m']:.3f} "
                f"| {r['qp_relaxed_ticks']} |"
            )
    t = summary["replanning_15_steps"]
    lines += ["", f"Replanning 15 steps with the learned policy: {t['median_ms']:.3f} ms (median)."]
    return "\n".join(lines) + "\n"


@hydra.main(version_base="1.3", config_path=None, config_name="push_recovery")
def main(cfg) -> None:
    s, out_dir = run_in_hydra(cfg, run)
    for name, count in s["recovered"].items():
        print(f"{name}: recovered {count}/{s['directions']} pushes of {s['impulse_Ns']:.0f} N s")
    print(
        f"15-step replanning: {s['replanning_15_steps']['median_ms']:.3f} ms; outputs in {out_dir}"
    )


if __name__ == "__main__":
    launch(main)
