"""The body-shaking reference of Section V-A (Fig. 10): an oscillating body orientation.

A rotation vector ``r(t) = s(t) (a_r sin wt, a_p sin(wt + pi/2), a_y sin wt)`` applied to
the body's rest orientation ``q0``, with the amplitude envelope ``s`` rising smoothly
(3u^2 - 2u^3) from 0 to 1 over ``ramp`` seconds. The feed-forward is the exact world-frame
angular velocity and acceleration of ``exp(r(t)) q0``, by differentiating the quaternion
in time (``omega = 2 qdot q^-1``): ``rdot`` and ``rddot`` with the envelope held constant
are off while the amplitude ramps, and by ``O(|r| |rdot|)`` after.
"""

from __future__ import annotations

import jaxloco.dynamics.quiet_mjx  # noqa: F401  (before brax, whose math imports MJX)

# isort: split
import dataclasses

import jax
import jax.numpy as jnp
from brax import math as quat_math

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class ShakingParams:
    roll_amplitude: float = 0.15
    """Roll amplitude of the body's rotation vector (rad)."""
    pitch_amplitude: float = 0.1
    """Pitch amplitude (rad)."""
    yaw_amplitude: float = 0.3
    """Rotation-vector amplitudes (rad)."""
    frequency_hz: float = 1.0
    """Shaking frequency (Hz)."""
    ramp: float = 0.5
    """Seconds over which the amplitude ramps up from zero (0: no ramp)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *(
                    (n, 0 <= getattr(self, n) <= 1.0, "in [0, 1] rad")
                    for n in ("roll_amplitude", "pitch_amplitude", "yaw_amplitude")
                ),
                ("frequency_hz", 0 < self.frequency_hz <= 10, "in (0, 10] Hz"),
                ("ramp", self.ramp >= 0, ">= 0 s"),
            ],
        )


def shaking_reference(params: ShakingParams, q0, t, frequency_hz=None):
    """Body orientation reference at time ``t``: (quaternion, world-frame angular velocity,
    angular acceleration). ``frequency_hz`` (may be traced, e.g. vmapped over a batch of
    frequencies) overrides ``params.frequency_hz``."""
    t = jnp.asarray(t, jnp.result_type(float))
    freq = params.frequency_hz if frequency_hz is None else frequency_hz
    one = jnp.ones_like(t)
    vel, acc = jax.jvp(lambda s: _angular_velocity(params, s, freq), (t,), (one,))
    return quat_math.quat_mul(_exp(_rotation_vector(params, t, freq)), q0), vel, acc


def _rotation_vector(params: ShakingParams, t, frequency_hz):
    w = 2 * jnp.pi * frequency_hz
    amp = jnp.asarray([params.roll_amplitude, params.pitch_amplitude, params.yaw_amplitude])
    phase = jnp.asarray([0.0, jnp.pi / 2, 0.0])
    if params.ramp > 0:
        u = jnp.clip(t / params.ramp, 0.0, 1.0)
        envelope = u * u * (3.0 - 2.0 * u)
    else:
        envelope = 1.0
    return envelope * amp * jnp.sin(w * t + phase)


def _angular_velocity(params: ShakingParams, t, frequency_hz):
    quat, quat_dot = jax.jvp(
        lambda s: _exp(_rotation_vector(params, s, frequency_hz)), (t,), (jnp.ones_like(t),)
    )
    return 2.0 * quat_math.quat_mul(quat_dot, quat_math.quat_inv(quat))[1:]


def _exp(rotvec):
    """Unit quaternion of a rotation vector, smooth (with its derivatives) at zero: both
    ``cos(|r|/2)`` and ``sin(|r|/2)/|r|`` are taken as functions of ``|r|^2``."""
    sq = rotvec @ rotvec
    small = sq < 1e-8
    safe = jnp.where(small, 1.0, sq)
    angle = jnp.sqrt(safe)
    cos_half = jnp.where(small, 1.0 - sq / 8.0 + sq * sq / 384.0, jnp.cos(angle / 2))
    sinc_half = jnp.where(small, 0.5 - sq / 48.0 + sq * sq / 3840.0, jnp.sin(angle / 2) / angle)
    return jnp.concatenate([cos_half[None], sinc_half * rotvec])
