"""Start states for training and evaluation: pushed nominal states and uniform draws.

Paper Section II-C and the authors' code: the nominal apex state
``(0.056, 0.2, 0)`` hit by impulses of 10, 30 and 50 N s over 0.1 s at angles from -90 to
90 degrees on a 136 kg LIPM, with noise of about two grid spacings; and uniform draws over
the state box of Eq. 1.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxloco import validation as v
from jaxloco.planner import PSPParams, lipm


@dataclasses.dataclass(frozen=True)
class StartStates:
    """How start states are drawn."""

    box_low: tuple[float, float, float] = (-0.14, 0.03, -0.55)
    """Lower corner of the apex state box of Eq. 1 (y, xd, yd; m, m/s, m/s)."""
    box_high: tuple[float, float, float] = (0.20, 0.61, 0.55)
    """The apex state box of Eq. 1 (y, xd, yd)."""
    pushed_fraction: float = 0.5
    """Share of pushed nominal states; the rest are uniform over the box."""
    mass: float = 136.0
    """Robot mass (kg) that turns a push's impulse into a velocity change."""
    impulses: tuple[float, ...] = (10.0, 30.0, 50.0)
    """Push impulses (N s)."""
    push_duration: float = 0.1
    """Duration of the pushes (s)."""
    angle_min_deg: float = -90.0
    """Smallest push direction (deg from the walking direction)."""
    angle_max_deg: float = 90.0
    """Push directions, from the walking direction (0) towards the swing side (+90)."""
    noise: float = 0.04
    """Standard deviation of the noise added to pushed states (two grid spacings)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *v.unit_interval(self, "pushed_fraction"),
                (
                    "box_low",
                    all(lo < hi for lo, hi in zip(self.box_low, self.box_high, strict=True)),
                    f"< box_high = {self.box_high} on every axis",
                ),
                *v.positive(self, "mass", "push_duration"),
                *v.non_negative(self, "noise"),
                ("impulses", len(self.impulses) > 0, "a non-empty list"),
            ],
        )


@dataclasses.dataclass(frozen=True)
class EpisodeTurns:
    """Heading changes during training episodes (steering: Fig. 3b, Fig. 11).

    After each step the next local frame is turned and the CoM state re-projected into it,
    as :func:`jaxloco.planner.plan_steps` does when steering, so the policy learns the
    (generally larger lateral-velocity) apex states that turning produces. The paper's
    training walks straight (``max_deg = 0``).
    """

    max_deg: float = 0.0
    """A turning episode turns by one heading change per step, drawn uniformly from
    ``[-max_deg, max_deg]`` degrees (0: every episode walks straight)."""
    fraction: float = 0.5
    """Share of episodes that turn; the rest walk straight."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                ("max_deg", 0.0 <= self.max_deg < 90.0, "in [0, 90)"),
                *v.unit_interval(self, "fraction"),
            ],
        )

    @property
    def enabled(self) -> bool:
        return self.max_deg > 0.0 and self.fraction > 0.0


def episode_turns(key, n: int, spec: EpisodeTurns, dtype=None):
    """``(n,)`` per-step heading changes (rad), one per episode (0 for straight episodes)."""
    dtype = dtype or jnp.zeros(()).dtype
    k_turn, k_mix = jax.random.split(key)
    limit = jnp.deg2rad(jnp.asarray(spec.max_deg, dtype))
    turn = jax.random.uniform(k_turn, (n,), dtype, -limit, limit)
    return jnp.where(jax.random.uniform(k_mix, (n,)) < spec.fraction, turn, 0.0)


def uniform_states(key, n: int, spec: StartStates = StartStates(), dtype=None):
    """``(n, 3)`` apex states drawn uniformly from the box."""
    dtype = dtype or jnp.zeros(()).dtype
    return jax.random.uniform(
        key, (n, 3), dtype, jnp.asarray(spec.box_low, dtype), jnp.asarray(spec.box_high, dtype)
    )


def push_apex_state(impulse, angle, psp: PSPParams, spec: StartStates):
    """The apex state after pushing the nominal gait at its apex (one push).

    A constant force ``F = impulse / duration`` acts for ``duration``: the LIPM with a
    constant force is the LIPM about a pivot shifted by ``-F / (m w^2)``. The pushed state is
    then carried along its free orbit to (or back to) the apex. Returns ``(state, valid)``;
    invalid where the pushed CoM no longer crosses the stance foot moving forward.
    """
    w = psp.omega
    y0, xd0, yd0 = psp.nominal_state
    force = impulse / spec.push_duration
    fx, fy = force * jnp.cos(angle), force * jnp.sin(angle)
    shift = 1.0 / (spec.mass * w**2)
    x1, xd1 = lipm.propagate(0.0, xd0, -fx * shift, w, spec.push_duration)
    y1, yd1 = lipm.propagate(y0, yd0, -fy * shift, w, spec.push_duration)
    t_apex, xd_apex, growth, valid = lipm.apex_growth_of(x1, xd1, 0.0, w)
    y_apex, yd_apex = lipm.propagate_by_growth(y1, yd1, 0.0, w, growth)
    return jnp.stack([y_apex, xd_apex, yd_apex]), valid


def pushed_states(key, n: int, psp: PSPParams = PSPParams(), spec: StartStates = StartStates()):
    """``(n, 3)`` pushed nominal states with noise; pushes that stop the CoM are redrawn
    uniformly from the box (shapes stay static)."""
    k_imp, k_ang, k_noise, k_fill = jax.random.split(key, 4)
    impulses = jax.random.choice(k_imp, jnp.asarray(spec.impulses), (n,))
    angles = jnp.deg2rad(
        jax.random.uniform(k_ang, (n,), minval=spec.angle_min_deg, maxval=spec.angle_max_deg)
    )
    states, valid = jax.vmap(lambda j, a: push_apex_state(j, a, psp, spec))(impulses, angles)
    states = states + spec.noise * jax.random.normal(k_noise, states.shape, states.dtype)
    fill = uniform_states(k_fill, n, spec, states.dtype)
    return jnp.where(valid[:, None], states, fill)


def training_starts(key, n: int, psp: PSPParams = PSPParams(), spec: StartStates = StartStates()):
    """``(n, 3)`` start states: ``pushed_fraction`` pushed, the rest uniform."""
    k_push, k_uni, k_mix = jax.random.split(key, 3)
    pushed = pushed_states(k_push, n, psp, spec)
    uniform = uniform_states(k_uni, n, spec, pushed.dtype)
    use_pushed = jax.random.uniform(k_mix, (n,)) < spec.pushed_fraction
    return jnp.where(use_pushed[:, None], pushed, uniform)
