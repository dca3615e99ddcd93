"""The body-shaking reference of Section V-A (Fig. 10): an oscillating body orientation.

A rotation vector ``(a_r sin wt, a_p sin(wt + pi/2), a_y sin wt)`` applied to the body's
rest orientation ``q0``, its rate and acceleration as feed-forward (exact to first order in
the angle), with the amplitude ramped up from zero over ``ramp`` seconds.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
from mujoco.mjx._src import math as mjx_math


@dataclasses.dataclass(frozen=True)
class ShakingParams:
    roll_amplitude: float = 0.15
    pitch_amplitude: float = 0.1
    yaw_amplitude: float = 0.3
    """Rotation-vector amplitudes (rad)."""
    frequency_hz: float = 1.0
    ramp: float = 0.5
    """Seconds over which the amplitude ramps up from zero (0: no ramp)."""

    def __post_init__(self):
        for name in ("roll_amplitude", "pitch_amplitude", "yaw_amplitude"):
            if not 0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"ShakingParams.{name} must be in [0, 1] rad")
        if not 0 < self.frequency_hz <= 10:
            raise ValueError(
                f"ShakingParams.frequency_hz must be in (0, 10]; got {self.frequency_hz}"
            )
        if self.ramp < 0:
            raise ValueError(f"ShakingParams.ramp must be >= 0 s; got {self.ramp}")


def shaking_reference(params: ShakingParams, q0, t):
    """Body orientation reference at time ``t``: (quaternion, angular velocity, acceleration)."""
    w = 2 * jnp.pi * params.frequency_hz
    amp = jnp.asarray([params.roll_amplitude, params.pitch_amplitude, params.yaw_amplitude])
    phase = jnp.asarray([0.0, jnp.pi / 2, 0.0])
    ramp = jnp.clip(t / params.ramp, 0.0, 1.0) if params.ramp > 0 else 1.0
    rot = ramp * amp * jnp.sin(w * t + phase)
    vel = ramp * amp * w * jnp.cos(w * t + phase)
    acc = -ramp * amp * w**2 * jnp.sin(w * t + phase)
    return mjx_math.quat_mul(_exp(rot), q0), vel, acc


def _exp(rotvec):
    angle = jnp.sqrt(rotvec @ rotvec + 1e-30)
    return jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) / angle * rotvec])
