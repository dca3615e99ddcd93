"""The whole body within its effort limits: WBLC's last stage, a bounded least-squares
change of the torques.

The hierarchy and the force QP give torques ``tau`` (Eq. 19) that may exceed some joint's
limit: the force QP's torque rows reach only the joints that carry a foot, and the upper
body's torques are whatever its tasks ask. With the contact forces held, a torque change
``dtau`` changes the accelerations by ``dqdd = A^-1 U' dtau`` (Eq. 11), so the smallest
change that brings every torque within its limit while the feet in contact stay held is::

    min  sum_j (dtau_j / limit_j)^2
    s.t. J_c A^-1 U' dtau = 0                  (the contact tasks' accelerations kept)
         |tau + dtau| <= limit                 (every actuator)

in units of each actuator's limit, so a wrist's 5 N m and a knee's 139 N m count alike.
The other tasks give way by ``J_k dqdd``, reported per task (:attr:`TorqueLimitSolution`
and ``WBLCDiagnostics.task_relaxation``): the arms and torso follow their tasks less, and
the floating base takes the reaction of their changed accelerations (the forces are
held, so the robot's momentum rate is too). Where no change within the limits holds the
feet, the torques still come back within the limits and ``held_residual`` says by how
much the held feet's acceleration is missed.

**Solver.** ADMM on ``x = z`` (Boyd et al., 2011), ``x`` in the null space of the held
rows and ``z`` in the box: the ``x``-step is the projection of ``rho / (1 + rho) (z - u)``
onto that null space (one ``nu x nu`` product, the projector formed once per call), the
``z``-step a clip. When the torques are already within their limits ``x = z = u = 0`` is
the fixed point and the stage changes nothing. The returned torques are ``tau + limit z``:
within the limits exactly; the held rows are met to ``held_residual``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco import validation as v
from jaxloco.control.pinv import pinv_psd


@dataclasses.dataclass(frozen=True)
class TorqueLimitParams:
    """Settings of the limit stage's ADMM."""

    iterations: int = 60
    """ADMM iterations (a ``fori_loop``). Against quadprog on 100 random problems with
    a third of the torques over their limits (nv 35, nu 29, 12 held rows): median relative
    objective error 6e-7, 90th percentile 4e-5 (``tests/test_torque_limits.py``)."""
    rho: float = 3.0
    """ADMM penalty, in units of the objective's (unit) Hessian: 3 met quadprog best of
    0.3, 1, 3 and 10 at 60 iterations."""
    held_rtol: float = 1e-6
    """Rank threshold of the held rows' ``B B'`` relative to its largest eigenvalue."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.integer(self, "iterations", 1),
                *v.positive(self, "rho"),
                ("held_rtol", 0 < self.held_rtol < 1, "in (0, 1)"),
            ],
        )


@struct.dataclass
class TorqueLimitSolution:
    """The limit stage's result."""

    torques: jax.Array
    """(nu,) actuator torques within their limits (N m, actuator order)."""
    torque_change: jax.Array
    """(nu,) the change from the requested torques (N m); 0 where none was needed."""
    acceleration_change: jax.Array
    """(nv,) ``A^-1 U' dtau``: what the change does to the joint accelerations, the
    contact forces held (rad/s^2, m/s^2 on the free joint's translation)."""
    held_residual: jax.Array
    """() the largest held-row acceleration the change leaves (m/s^2 or rad/s^2 on the
    contact tasks' rows): 0 when the feet stay held exactly."""
    active: jax.Array
    """() bool, the requested torques exceeded some limit and were changed."""


def limit_torques(
    torques,
    limits,
    selection,
    mass_cholesky_inverse,
    held_jacobian,
    params: TorqueLimitParams = TorqueLimitParams(),
) -> TorqueLimitSolution:
    """The smallest change of ``torques`` (nu,) that brings them within ``limits`` (nu,;
    ``inf``: unlimited) while the rows ``held_jacobian`` (m, nv; zero rows are free) keep
    their acceleration (see the module doc).

    ``selection``: (nu, nv) ``U``, the actuators' map to joint torques;
    ``mass_cholesky_inverse``: (nv, nv) ``L^-1`` with ``L L' = A``."""
    dtype = torques.dtype
    finite = jnp.isfinite(limits)
    scale = jnp.where(finite, limits, 1.0)
    lower = jnp.where(finite, (-limits - torques) / scale, -jnp.inf)
    upper = jnp.where(finite, (limits - torques) / scale, jnp.inf)
    # dqdd per unit of x (scaled torque change): A^-1 U' diag(scale) = L^-T (L^-1 U') diag.
    whitened = mass_cholesky_inverse @ (selection.T * scale[None, :])  # (nv, nu)
    response = mass_cholesky_inverse.T @ whitened  # (nv, nu)
    held = held_jacobian @ response  # (m, nu)
    projector = jnp.eye(held.shape[1], dtype=dtype)
    if held.shape[0]:
        projector = projector - held.T @ (pinv_psd(held @ held.T, params.held_rtol) @ held)
    shrink = params.rho / (1.0 + params.rho)

    def iteration(_, zu):
        z, u = zu
        x = projector @ (shrink * (z - u))
        z_new = jnp.clip(x + u, lower, upper)
        return z_new, u + x - z_new

    zero = jnp.zeros_like(torques)
    start = jnp.clip(zero, lower, upper)
    z, _ = jax.lax.fori_loop(0, params.iterations, iteration, (start, zero))
    change = scale * z
    over = jnp.any((torques < -limits) | (torques > limits))
    held_acc = held @ z
    return TorqueLimitSolution(
        # The clip only removes rounding: tau + limit * (limit - tau) / limit is the limit
        # to a few ulps of |tau|, which in float32 is beyond 1e-5 of a wrist's 5 N m.
        torques=jnp.clip(torques + change, -limits, limits),
        torque_change=change,
        acceleration_change=response @ z,
        held_residual=jnp.max(jnp.abs(held_acc), initial=0.0),
        active=over,
    )
