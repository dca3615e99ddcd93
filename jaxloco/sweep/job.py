"""One frozen description of a sweep's work: what every executor hands its chunk runner.

A :class:`SweepJob` holds everything a process needs to run any chunk of a sweep, and
nothing that depends on the process: the run directory (where the push table, the
undisturbed walks and the chunks live, :mod:`.store`), the controller's and the physics'
settings, the backend, and how each push is run. It pickles, so the same job goes to a
thread, a local worker process or a worker on another machine, and every one of them runs
a chunk the same way (:class:`~jaxloco.sweep.chunks.ChunkRunner`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from jaxloco import validation as v
from jaxloco.control.wblc import WBLCConfig
from jaxloco.learning.loading import checkpoint_digest
from jaxloco.locomotion import GaitParams
from jaxloco.robots import DEFAULT_ROBOT, ROBOTS
from jaxloco.sim.mjx_loop import PhysicsParams
from jaxloco.sweep.spec import SweepSpec

BACKENDS = ("c", "mjx")


@dataclasses.dataclass(frozen=True)
class SweepJob:
    """A sweep's chunks, as any process runs them."""

    run_dir: str
    """The sweep's run directory (shared by every worker: a local path, or a shared file
    system on a cluster)."""
    walks_dir: str | None = None
    """Where the undisturbed walks are kept; None: ``run_dir/walks``. Sweeps with the same
    settings may share one (the rounds of a limit search do)."""
    backend: str = "c"
    """``"c"`` (MuJoCo C batch + vmapped JAX controller) or ``"mjx"``."""
    chunk_size: int = 16
    """Pushes per batched backend call; the last chunk is padded to it."""
    gait: GaitParams = GaitParams()
    """The walking controller's gait numbers."""
    physics: PhysicsParams = PhysicsParams()
    """The simulation's settings (solver, torque limits)."""
    wblc: WBLCConfig | None = None
    """The WBLC's configuration; None: the walking preset."""
    robot: str = DEFAULT_ROBOT.name
    """The robot (:data:`jaxloco.robots.ROBOTS`) whose model, keyframe and feet the sweep
    uses."""
    push_body: str = DEFAULT_ROBOT.base_body
    """The body the pushes act on."""
    push_step: int = 4
    """The step (counted from the first lift-off) during which pushes start."""
    horizon: float = 2.5
    """Simulated seconds from each push's start."""
    steps_after: int = 2
    """Steps that must begin after the push for it to count as recovered."""
    qvel_noise: float = 0.0
    """Std (rad/s, m/s) of the joint-velocity noise at each push's start (seeded per row)."""
    fall_height: float = 0.7
    """Pelvis height (m) below which the robot has fallen."""
    x64: bool = False
    """Run the controller in float64."""
    cache_dir: str | None = None
    """JAX's persistent compilation cache, so workers load the compiled tick."""
    nthread: int | None = None
    """Threads of the C backend's physics batch (None: all cores of the process)."""
    planner: str | None = None
    """The step policy: a checkpoint folder (:func:`~jaxloco.learning.load_planner`); None:
    the shipped default. Outcomes depend on its contents, not on its path
    (:meth:`outcome_settings`)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.one_of(self, "backend", BACKENDS),
                v.one_of(self, "robot", tuple(ROBOTS)),
                v.integer(self, "chunk_size", 1),
                v.integer(self, "push_step", 1),
                v.integer(self, "steps_after", 0),
                *v.positive(self, "horizon", "fall_height"),
                *v.non_negative(self, "qvel_noise"),
            ],
        )

    @classmethod
    def of(cls, spec: SweepSpec, run_dir, **settings) -> SweepJob:
        """The job running ``spec``'s pushes into ``run_dir``."""
        return cls(
            run_dir=str(run_dir),
            push_step=spec.push_step,
            horizon=spec.horizon,
            steps_after=spec.steps_after,
            qvel_noise=spec.qvel_noise,
            fall_height=spec.fall_height,
            **settings,
        )

    def replace(self, **changes) -> SweepJob:
        return dataclasses.replace(self, **changes)

    def outcome_settings(self) -> dict:
        """What the outcome of a chunk depends on besides its pushes (JSON values): a run
        directory whose chunks were written with other settings is another sweep."""
        keep = dataclasses.asdict(self)
        for k in ("run_dir", "walks_dir", "cache_dir", "nthread"):
            keep.pop(k)
        keep["planner"] = checkpoint_digest(self.planner)
        return json.loads(json.dumps(keep, default=str))

    def settings_digest(self) -> str:
        """A short hash of :meth:`outcome_settings` (a worker keeps one prepared runner
        per digest, whatever the run directory)."""
        text = json.dumps(self.outcome_settings(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def walk_path(self, key: tuple) -> Path:
        """Where the undisturbed walk ``(apex_speed, turn_deg, replan)`` is kept."""
        speed, turn, replan = key
        folder = Path(self.walks_dir) if self.walks_dir else Path(self.run_dir) / "walks"
        return folder / f"{speed!r}_{turn!r}_{int(replan)}.npz"
