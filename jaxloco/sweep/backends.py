"""Physics backends of a sweep: a chunk of pushed runs, one vmapped controller call a tick.

- :class:`MJXBackend`: the whole chunk is one jitted, vmapped ``lax.scan`` of the MJX
  closed loop (:func:`jaxloco.sim.mjx_loop.closed_loop_step`); with several JAX devices
  the chunk is sharded across them along the batch axis (``jax.sharding``). The path to
  accelerators and to gradients.
- :class:`CBatchBackend`: MuJoCo's C engine for the chunk (``mujoco.batch.Batch``, a
  thread pool over the simulations), with the same walking controller jitted and vmapped
  over the chunk (not vmapped for a chunk of one robot), called once per tick from
  Python. Compiles only the controller.

Both take start states from :mod:`.starts` and return one :class:`~.outcome.Outcome` per
run; a fallen robot is frozen from its fall on (MJX: its state stops changing; C: it is no
longer stepped).
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from mujoco import batch as mj_batch

from jaxloco.dynamics.engine_terms import EngineTerms, bind_engine_terms, check_same_dynamics
from jaxloco.dynamics.quiet_mjx import mjx
from jaxloco.locomotion.walking import WalkingController, WalkingState
from jaxloco.runtime import single_thread_compiler_options
from jaxloco.sim.mjx_loop import LoopState, closed_loop_step, mjx_data_from_c
from jaxloco.sim.packing import HostGather, TreeLayout
from jaxloco.sim.push import PushArrays, push_force
from jaxloco.sweep.outcome import Outcome, init_outcome, mark_fallen, update_outcome
from jaxloco.sweep.starts import STATE_SPEC


@dataclasses.dataclass
class ChunkStarts:
    """Start states of a chunk's runs (leading axis: runs)."""

    times: np.ndarray
    """(runs,) simulated time of each run's start (s)."""
    physics: np.ndarray
    """``mjSTATE_INTEGRATION`` rows."""
    controller: WalkingState
    """Each run's walking-controller state (leading axis: runs)."""
    pushes: PushArrays
    """Each run's push, fields of shape (B,), world frame."""


def mjx_loop_states(sim_model: mujoco.MjModel, starts: ChunkStarts, mx=None) -> LoopState:
    """MJX closed-loop states (leading axis: runs) from a chunk's start states."""
    m, d = sim_model, mujoco.MjData(sim_model)
    mx = mjx.put_model(m) if mx is None else mx
    datas = []
    for row in starts.physics:
        mujoco.mj_setState(m, d, row, STATE_SPEC)
        mujoco.mj_forward(m, d)
        datas.append(mjx_data_from_c(mx, m, d))
    data = jax.tree.map(lambda *xs: jnp.stack(xs), *datas)
    n = len(starts.times)
    return LoopState(
        data,
        jax.tree.map(jnp.asarray, starts.controller),
        jnp.zeros(n, bool),
        jnp.full(n, jnp.inf, data.qpos.dtype),
    )


class CBatchBackend:
    """MuJoCo C engine for a batch of robots; the controller jitted and vmapped in JAX."""

    name = "c"

    def __init__(
        self,
        sim_model: mujoco.MjModel,
        ctrl: WalkingController,
        push_body: int,
        fall_height: float,
        nthread: int | None = None,
    ):
        self.model = sim_model
        self.push_body = push_body
        self.fall_height = fall_height
        self.nthread = nthread or os.cpu_count() or 1

        check_same_dynamics(ctrl.wblc.mx, sim_model)  # the controller reads the engine's terms
        self._ctrl = ctrl
        self._ticks = {}  # one compiled tick per layout of the controller state
        # A chunk's set-up and read-out, each one program (op by op, vmapped packing was
        # about 50 small compiles per chunk size in every new process).
        self._pack = {}
        self._unpack = {}
        self._layouts = {}  # packed layout per chunk input layout

    def _tick_for(self, layout: TreeLayout, host: TreeLayout, n: int):
        """The vmapped tick over ``n`` robots' packed states: ``(host, packed) -> (torques and push
        forces, packed)``; ``host`` each robot's row of ``(time, alive, engine)`` gathered
        by :class:`HostGather` (``host`` its layout), ``engine`` what MuJoCo C computed for
        the robot's state (:class:`~jaxloco.dynamics.engine_terms.EngineTerms`). Packing
        the controller state, the outcome and the push into one array per dtype, and the
        host's arrays into one, keeps the per-tick call to a handful of arrays (each array
        passed to a jitted call is converted on its own). For one robot the tick is not
        vmapped: the gait's conds stay conds (under ``vmap`` both branches run, the step
        planner's included), a shorter tick."""
        key = (layout, host, n == 1)
        if key not in self._ticks:
            ctrl = self._ctrl

            def tick(row, packed):
                t, alive, *fields = host.unpack({"float64": row})
                engine = EngineTerms(*fields)
                alive = alive > 0.5
                cstate, outcome, push = layout.unpack(packed)
                torques, new_cstate, log = ctrl.step(
                    t, engine.qpos, engine.qvel, cstate, engine=engine
                )
                outcome = update_outcome(outcome, log, alive)
                # A fallen robot keeps its controller state: one select per packed array,
                # not one per leaf (each a kernel of its own in the compiled program).
                new = layout.pack((new_cstate, outcome, push))
                old = layout.pack((cstate, outcome, push))
                packed = {k: jnp.where(alive, new[k], old[k]) for k in new}
                actions = jnp.concatenate([torques, push_force(push, t)])
                return actions, packed

            def one_robot(rows, packed):
                actions, packed = tick(rows[0], {k: v[0] for k, v in packed.items()})
                return actions[None], {k: v[None] for k, v in packed.items()}

            # Single-threaded kernels: faster on a sweep worker's one core. The same program
            # in every process, so outcomes do not depend on where a chunk runs.
            options = single_thread_compiler_options()
            fn = one_robot if n == 1 else jax.vmap(tick)
            self._ticks[key] = jax.jit(fn, compiler_options=options)
        return self._ticks[key]

    def _layout_for(self, cstate, pushes) -> TreeLayout:
        """The packed layout of one robot's ``(controller state, outcome, push)``, from the
        chunk's controller states and pushes (leading axis: robots); kept per input layout,
        as tracing ``init_outcome`` again costs milliseconds a run."""
        key = TreeLayout.of((cstate, pushes))
        if key not in self._layouts:
            one = jax.eval_shape(
                lambda c, p: (c, init_outcome(c), p),
                *jax.tree.map(
                    lambda x: jax.ShapeDtypeStruct(np.shape(x)[1:], x.dtype), (cstate, pushes)
                ),
            )
            self._layouts[key] = TreeLayout.of(one)
        return self._layouts[key]

    def run(self, starts: ChunkStarts, horizon_steps: int, progress=None) -> Outcome:
        m = self.model
        n = len(starts.times)
        # Persistent: each simulation keeps its MjData, so a step continues from the
        # position and velocity stages computed for the controller (no second pass).
        batch = mj_batch.Batch(m, n, nthread=self.nthread, persistent=True)
        if batch.nstate != starts.physics.shape[1]:
            raise ValueError("start states do not match the model's mjSTATE_INTEGRATION size")
        batch.state[:] = starts.physics
        batch.forward(stage=mujoco.mjtStage.mjSTAGE_VEL)
        engine = bind_engine_terms(batch)
        qpos, time = engine.qpos, batch.bind("time")
        ctrl, xfrc = batch.bind("ctrl"), batch.bind("xfrc_applied")
        alive = np.ones(n, bool)
        alive_f = np.ones(n)  # alive, as the float the host buffer carries
        host = HostGather((time, alive_f, *engine))
        pushes = PushArrays(*starts.pushes)
        layout = self._layout_for(starts.controller, pushes)
        tick = self._tick_for(layout, host.layout, n)
        if layout not in self._pack:
            self._pack[layout] = jax.jit(
                jax.vmap(lambda c, p: layout.pack((c, init_outcome(c), p)))
            )
            self._unpack[layout] = jax.jit(jax.vmap(lambda packed: layout.unpack(packed)[1]))
        packed = self._pack[layout](starts.controller, pushes)
        nu = m.nu
        t0 = starts.times.copy()
        fall_time = np.full(n, np.inf)
        for _ in range(horizon_steps):
            actions, packed = tick(host.gather(), packed)
            ids = np.flatnonzero(alive)
            if ids.size == 0:
                break
            actions = np.asarray(actions)
            ctrl[:] = actions[:, :nu]
            xfrc[:, self.push_body, :3] = actions[:, nu:]
            before = time.copy()
            batch.step(ids, stage=mujoco.mjtStage.mjSTAGE_VEL)
            fell = alive & (~np.all(np.isfinite(qpos), axis=1) | (qpos[:, 2] < self.fall_height))
            fall_time[fell] = before[fell] - t0[fell]
            alive &= ~fell
            alive_f[:] = alive
            if progress is not None:
                progress(n)
        outcome = self._unpack[layout](packed)
        fell = ~alive
        return outcome.replace(
            fell=jnp.asarray(fell),
            fall_time=jnp.asarray(np.where(fell, fall_time, np.inf), outcome.fall_time.dtype),
        )


class MJXBackend:
    """The chunk as one jitted, vmapped MJX rollout (sharded over devices when several)."""

    name = "mjx"

    def __init__(
        self,
        sim_model: mujoco.MjModel,
        ctrl: WalkingController,
        push_body: int,
        fall_height: float,
        horizon_steps: int,
        devices=None,
    ):
        self.model = sim_model
        check_same_dynamics(ctrl.wblc.mx, sim_model)  # the controller reads the engine's terms
        self.mx = mjx.put_model(sim_model)
        self.devices = list(devices) if devices is not None else jax.devices()
        self.horizon_steps = horizon_steps
        mx = self.mx

        def one(state: LoopState, outcome: Outcome, push):
            t0 = state.data.time

            def tick(carry, _):
                s, o = carry
                alive = ~s.fell
                s, record = closed_loop_step(mx, ctrl.step, s, push, push_body, fall_height)
                o = update_outcome(o, record.controller, alive)
                o = mark_fallen(o, s.fell, s.fall_time - t0)
                return (s, o), None

            (state, outcome), _ = jax.lax.scan(tick, (state, outcome), None, horizon_steps)
            return outcome

        batched = jax.vmap(one)
        if len(self.devices) > 1:
            mesh = Mesh(np.asarray(self.devices), ("batch",))
            self.sharding = NamedSharding(mesh, PartitionSpec("batch"))
            self._run = jax.jit(batched, out_shardings=self.sharding)
        else:
            self.sharding = None
            self._run = jax.jit(batched)

    @property
    def batch_multiple(self) -> int:
        """Chunk sizes must be a multiple of this (the number of devices)."""
        return len(self.devices)

    def run(self, starts: ChunkStarts, horizon_steps: int, progress=None) -> Outcome:
        if horizon_steps != self.horizon_steps:
            raise ValueError(
                f"MJXBackend compiled for {self.horizon_steps} steps, asked for {horizon_steps}"
            )
        n = len(starts.times)
        if n % self.batch_multiple:
            raise ValueError(f"chunk of {n} runs is not a multiple of {self.batch_multiple}")
        state = mjx_loop_states(self.model, starts, self.mx)
        outcome = jax.vmap(init_outcome)(state.controller)
        pushes = PushArrays(*starts.pushes).astype(state.data.qpos.dtype)
        args = (state, outcome, pushes)
        if self.sharding is not None:
            args = jax.device_put(args, self.sharding)
        out = jax.block_until_ready(self._run(*args))
        if progress is not None:
            progress(n * horizon_steps)
        return out
