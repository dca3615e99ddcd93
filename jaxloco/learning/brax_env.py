"""The PSP step task as a Brax environment, for Brax's learners (PPO, SAC, ...).

One environment step is one walking step of the phase-space planner: the observation is the
apex state ``(y_apex, xd_apex, yd_apex)`` in the stance-foot frame, the action the step
``(p_x, xd_apex_next, yd_apex_next)``, the reward Eq. 3 (``PSPParams.terminal_reward`` on a
step that breaks Eq. 4), and the episode ends at such a step. It runs
:func:`~jaxloco.planner.plan_step`, the same jitted function Algorithm 1 and the survival
basin use, and draws its starts as Algorithm 1 does (:func:`~.starts.training_starts`; the
default :data:`BOX_STARTS` draws them uniformly from the box of Eq. 1).

Brax's policies act in ``[-1, 1]`` (a tanh-squashed normal): :meth:`StepEnv.to_action`
maps that cube affinely onto the action box of Eq. 2, so every action the learner can take
is one the RBF policy could take. Episode length (the paper's 50 steps) is set where Brax
wraps the environment (``episode_length``), not here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from jaxloco.learning.starts import StartStates, training_starts
from jaxloco.planner import PSPParams, plan_step

BOX_STARTS = StartStates(pushed_fraction=0.0)
"""Starts drawn uniformly from the box of Eq. 1: the states the survival basin measures."""


def box_action(unit_action, psp: PSPParams):
    """Map ``(..., 3)`` actions in Brax's ``[-1, 1]`` cube affinely onto ``psp``'s action box
    (Eq. 2); actions outside the cube are clipped to it first."""
    low, high = jnp.asarray(psp.action_low), jnp.asarray(psp.action_high)
    u = jnp.clip(unit_action, -1.0, 1.0)
    return low + 0.5 * (u + 1.0) * (high - low)


class StepEnv(Env):
    """The PSP step MDP (see the module docstring). ``metrics``: ``safe_steps`` (1 per safe
    step), ``p_x``, ``p_y`` (m), ``t_switch`` (s) of the last step."""

    def __init__(self, psp: PSPParams = PSPParams(), starts: StartStates = BOX_STARTS):
        self.psp = psp
        self.starts = starts

    def to_action(self, unit_action):
        """:func:`box_action` on this task's action box."""
        return box_action(unit_action, self.psp)

    def reset(self, rng: jax.Array) -> State:
        apex = training_starts(rng, 1, self.psp, self.starts)[0]
        zero = jnp.zeros((), apex.dtype)
        metrics = {"safe_steps": zero, "p_x": zero, "p_y": zero, "t_switch": zero}
        return State(pipeline_state=None, obs=apex, reward=zero, done=zero, metrics=metrics)

    def step(self, state: State, action: jax.Array) -> State:
        plan = plan_step(state.obs, self.to_action(action), self.psp)
        # A terminal step's next state may be a placeholder: the episode ends where it was.
        obs = jnp.where(plan.terminal, state.obs, plan.next_state)
        dtype = state.obs.dtype
        metrics = {
            **state.metrics,  # wrappers add their own entries (Brax's episode reward)
            "safe_steps": (~plan.terminal).astype(dtype),
            "p_x": plan.p_x.astype(dtype),
            "p_y": plan.p_y.astype(dtype),
            "t_switch": plan.t_switch.astype(dtype),
        }
        return state.replace(
            obs=obs,
            reward=plan.reward.astype(dtype),
            done=plan.terminal.astype(dtype),
            metrics=metrics,
        )

    @property
    def observation_size(self) -> int:
        return 3

    @property
    def action_size(self) -> int:
        return 3

    @property
    def backend(self) -> str:
        # No physics pipeline: the planner is analytic.
        return "analytic"
