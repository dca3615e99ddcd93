"""Headless videos (GIF) of a run and top-view plots of footsteps and CoM paths.

:func:`render_gif` uses MuJoCo's own renderer when an OpenGL context can be made
(``MUJOCO_GL=egl`` on a GPU machine, ``osmesa`` where installed) and otherwise draws the
robot as a 3-D stick figure with matplotlib (bodies joined to their parents, the feet as
sole outlines): no display and no GL needed, so it works on any CI machine. Frames are
written with Pillow.
"""

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image


def _mujoco_frames(model, qpos_frames, width, height):
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception:  # noqa: BLE001 (no GL backend: any of several errors)
        return None
    data = mujoco.MjData(model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = 1
    cam.distance, cam.elevation, cam.azimuth = 4.0, -15.0, 135.0
    frames = []
    for q in qpos_frames:
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, cam)
        frames.append(Image.fromarray(renderer.render()))
    renderer.close()
    return frames


def _stick_frames(model, qpos_frames, width, height, times=None, title=""):
    data = mujoco.MjData(model)
    parents = model.body_parentid
    sole_sites = [
        [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{side}_foot_contact{k}")
            for k in (0, 1, 3, 2)
        ]
        for side in ("left", "right")
    ]
    frames = []
    dpi = 80
    for i, q in enumerate(qpos_frames):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
        canvas = FigureCanvasAgg(fig)
        ax = fig.add_subplot(projection="3d")
        pos = data.xpos
        for b in range(2, model.nbody):
            p = parents[b]
            if p == 0:
                continue
            ax.plot(*zip(pos[p], pos[b], strict=True), color="tab:blue", lw=2)
        for sites in sole_sites:
            if min(sites) >= 0:
                loop = data.site_xpos[sites + sites[:1]]
                ax.plot(loop[:, 0], loop[:, 1], loop[:, 2], color="tab:red", lw=1.5)
        c = data.subtree_com[1] if model.nbody > 1 else pos[0]
        ax.scatter(*c, color="k", s=12)
        ax.set_xlim(c[0] - 0.8, c[0] + 0.8)
        ax.set_ylim(c[1] - 0.8, c[1] + 0.8)
        ax.set_zlim(0.0, 1.6)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=15, azim=-60)
        ax.set_xticklabels([])
        ax.set_yticklabels([])
        ax.set_zticklabels([])
        label = title + (f"  t = {times[i]:.2f} s" if times is not None else "")
        ax.set_title(label, fontsize=9)
        canvas.draw()
        frames.append(Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3]))
    return frames


def render_gif(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    path: str | Path,
    times: np.ndarray | None = None,
    fps: int = 20,
    width: int = 480,
    height: int = 400,
    title: str = "",
    backend: str = "auto",
) -> Path:
    """Write a GIF of the trajectory ``qpos`` (T, nq) sampled at ``times`` (s).

    ``backend``: ``"mujoco"``, ``"stick"`` or ``"auto"`` (MuJoCo's renderer when it can
    start, else the stick figure). Frames are subsampled to ``fps`` of simulated time.
    """
    if backend not in ("auto", "mujoco", "stick"):
        raise ValueError(f"render_gif backend: 'auto', 'mujoco' or 'stick'; got {backend!r}")
    qpos = np.asarray(qpos)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ValueError(f"qpos must be (T, nq={model.nq}); got {qpos.shape}")
    if times is None:
        times = np.arange(len(qpos)) * model.opt.timestep
    times = np.asarray(times)
    keep = [0]
    for i, t in enumerate(times):
        if t >= times[keep[-1]] + 1.0 / fps - 1e-9:
            keep.append(i)
    frames = None
    # GLFW (MuJoCo's default GL backend) needs a display; without one a second attempt in
    # the same process has aborted it (libc++ "recursive initialization"), so "auto" only
    # tries MuJoCo's renderer where a headless backend is chosen or a display exists.
    gl_possible = os.environ.get("MUJOCO_GL", "").lower() in ("egl", "osmesa") or bool(
        os.environ.get("DISPLAY")
    )
    if backend == "mujoco" or (backend == "auto" and gl_possible):
        frames = _mujoco_frames(model, qpos[keep], width, height)
        if frames is None and backend == "mujoco":
            raise RuntimeError("MuJoCo's renderer could not start (set MUJOCO_GL=egl or osmesa)")
    if frames is None:
        frames = _stick_frames(model, qpos[keep], width, height, times[keep], title)
    path = Path(path)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return path


def plot_top_view(ax, com_xy, feet_xy=None, footsteps=None, stance=None, label="CoM", **kw):
    """Top view: the CoM path and the footsteps (world x-y) on a matplotlib axis."""
    ax.plot(com_xy[:, 0], com_xy[:, 1], label=label, **kw)
    if footsteps is not None and len(footsteps):
        footsteps = np.asarray(footsteps)
        colors = (
            None if stance is None else np.where(np.asarray(stance) == 0, "tab:green", "tab:red")
        )
        ax.scatter(footsteps[:, 0], footsteps[:, 1], marker="s", s=25, c=colors, zorder=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)


def stance_footsteps(time, stance, feet):
    """Footholds from a per-tick log: at each stance change the new stance foot's position.

    Returns ``(times, side, positions (K, 3))`` (side 0 left, 1 right)."""
    stance = np.asarray(stance)
    idx = np.concatenate([[0], np.nonzero(np.diff(stance))[0] + 1])
    side = stance[idx]
    pos = np.asarray(feet)[idx, side]
    return np.asarray(time)[idx], side, pos
