"""The closed loop on MuJoCo C: a pure controller run packed (``PackedController``) moves
the robot as the same controller called leaf by leaf, and keeps its carry and log."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxloco.dynamics.model import load_valkyrie
from jaxloco.robots import VALKYRIE
from jaxloco.sim import PackedController, run_closed_loop

TICKS = 60


@pytest.fixture(scope="module")
def model():
    return load_valkyrie()


def pd_controller(model, traces=None):
    """PD to the keyframe plus gravity compensation from the engine's bias forces; the
    carry counts ticks (int32) and sums the torque norm (float); the log mixes dtypes."""
    q0 = jnp.asarray(VALKYRIE.keyframe_qpos(model)[7:])
    nu = model.nu

    def controller(t, qpos, qvel, carry, engine=None):
        if traces is not None:
            traces.append(1)  # runs once per trace, not per tick
        ticks, effort = carry
        torques = 200.0 * (q0 - qpos[7:]) - 10.0 * qvel[6:]
        if engine is not None:
            torques = torques + engine.qfrc_bias[6 : 6 + nu]
        norm = jnp.linalg.norm(torques)
        log = {"t": t, "tick": ticks, "norm": norm, "far": norm > 50.0, "q": qpos[:3]}
        return torques, (ticks + 1, effort + norm), log

    return controller


def start(model):
    data = mujoco.MjData(model)
    data.qpos[:] = VALKYRIE.keyframe_qpos(model)
    mujoco.mj_forward(model, data)
    return data


def carry0():
    return (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.result_type(float)))


@pytest.mark.parametrize("engine", [False, True])
def test_a_packed_controller_moves_the_robot_as_the_call_leaf_by_leaf(model, engine):
    controller = pd_controller(model)
    plain, plain_carry = run_closed_loop(
        model, start(model), jax.jit(controller), carry0(), TICKS, engine=engine, pure=False
    )
    packed, packed_carry = run_closed_loop(
        model, start(model), controller, carry0(), TICKS, engine=engine
    )
    assert len(packed.time) == len(plain.time) == TICKS
    np.testing.assert_allclose(packed.ctrl, plain.ctrl, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(packed.qpos, plain.qpos, atol=1e-6)
    # The log keeps the controller's structure and dtypes, stacked over ticks.
    assert jax.tree.structure(packed.outputs) == jax.tree.structure(plain.outputs)
    for a, b in zip(jax.tree.leaves(packed.outputs), jax.tree.leaves(plain.outputs), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_array_equal(packed.outputs["tick"], np.arange(TICKS))
    np.testing.assert_allclose(packed.outputs["t"], packed.time, atol=1e-6)
    np.testing.assert_array_equal(packed.outputs["far"], plain.outputs["far"])
    assert int(packed_carry[0]) == int(plain_carry[0]) == TICKS
    np.testing.assert_allclose(packed_carry[1], plain_carry[1], rtol=1e-5)


def test_a_packed_controller_traces_once_across_runs_and_done_reads_its_log(model):
    traces = []
    controller = PackedController(pd_controller(model, traces))
    first, _ = run_closed_loop(model, start(model), controller, carry0(), 5, engine=True)
    traced = len(traces)
    assert traced >= 1
    # A second run from a carry of the same layout reuses the compiled tick; ``done``
    # gets each tick's log as the controller's pytree.
    seen = []
    second, carry = run_closed_loop(
        model,
        start(model),
        controller,
        carry0(),
        TICKS,
        engine=True,
        done=lambda log: seen.append(int(log["tick"])) or int(log["tick"]) >= 9,
    )
    assert len(traces) == traced
    assert seen == list(range(10)) and len(second.time) == 10 and int(carry[0]) == 10
    np.testing.assert_array_equal(second.qpos[:5], first.qpos)
    # No tick: no log, and the carry comes back as given.
    none, carry = run_closed_loop(model, start(model), controller, carry0(), 0, engine=True)
    assert none.outputs is None and len(none.time) == 0
    assert isinstance(carry[1], jax.Array) and int(carry[0]) == 0


def test_an_impure_controller_or_a_changing_carry_is_refused_clearly(model):
    def numpy_controller(t, qpos, qvel, carry):
        return np.zeros(model.nu) * np.asarray(qpos)[0], carry, {}

    with pytest.raises(TypeError, match="pure=False"):
        run_closed_loop(model, start(model), numpy_controller, None, 3)
    # The same controller called as Python runs.
    log, _ = run_closed_loop(model, start(model), numpy_controller, None, 3, pure=False)
    assert len(log.time) == 3

    def growing(t, qpos, qvel, carry):
        return jnp.zeros(model.nu), jnp.concatenate([carry, carry]), {}

    with pytest.raises(ValueError, match="carry of another structure, shape or dtype"):
        run_closed_loop(model, start(model), growing, jnp.zeros(2), 3)
