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

**Solver.** ADMM on ``x = z`` (Boyd et al., 2011), ``z`` in the box. The held rows
``B = J_c A^-1 U' diag(limit)`` enter the ``x``-step as a stiff penalty ``|B x|^2 /
delta`` (``delta``: ``held_rtol`` times the largest diagonal entry of ``B B'``), so the
``x``-step is ``(I - B' (B B' + delta' I)^-1 B) rho / (1 + rho) (z - u)`` by Woodbury's
identity, with ``delta' = (1 + rho) delta``: one Cholesky factorisation of the (m x m)
``B B' + delta' I`` per call, then one ``nu x nu`` product an iteration; the ``z``-step is a
clip. A held direction along which ``B B'`` has eigenvalue ``s`` keeps the fraction
``delta' / (s + delta')`` of the motion it would have free: the directions torques reach
well are held to round-off, the rows of a foot out of contact (zero) are free, and those
torques can hardly reach (``s`` near ``delta'``) are held in part, which
``held_residual`` reports. When the torques are already within their limits
``x = z = u = 0`` is the fixed point and the stage changes nothing. The returned torques
are ``tau + limit z``: within the limits exactly.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class TorqueLimitParams:
    """Settings of the limit stage's ADMM."""

    iterations: int = 60
    """ADMM iterations (a ``fori_loop``). Against quadprog on 100 random problems with
    a third of the torques over their limits (nv 35, nu 29, 12 held rows): median relative
    objective error 5e-7, 90th percentile 5e-5 in float64 (``tests/test_torque_limits.py``)."""
    rho: float = 3.0
    """ADMM penalty, in units of the objective's (unit) Hessian: 3 met quadprog best of
    0.3, 1, 3 and 10 at 60 iterations."""
    held_rtol: float = 1e-8
    """The held rows' penalty ``delta`` relative to the largest diagonal entry of ``B B'``
    (see the module doc); never below 10 machine epsilons of the dtype (1.2e-6 in
    float32), which keeps ``B B' + delta' I`` positive definite under round-off."""

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
    x_map = jnp.eye(held.shape[1], dtype=dtype)  # the x-step: (I + B'B / delta')^-1
    shrink = params.rho / (1.0 + params.rho)
    if held.shape[0]:
        gram = held @ held.T
        relative = max(params.held_rtol, 10.0 * float(jnp.finfo(dtype).eps))
        size = jnp.maximum(jnp.max(jnp.diagonal(gram)), jnp.finfo(dtype).tiny)
        damping = (1.0 + params.rho) * relative * size
        # A Cholesky factor, not an eigendecomposition: batched, LAPACK's eigh runs one
        # call per robot, and took about half of the stage's time (docs/control.md).
        factor = jax.scipy.linalg.cho_factor(
            gram + damping * jnp.eye(gram.shape[0], dtype=dtype), lower=True
        )
        held_map = x_map - held.T @ jax.scipy.linalg.cho_solve(factor, held)
        # Never NaN: a factorisation that failed holds nothing (``held_residual`` says so).
        x_map = jnp.where(jnp.all(jnp.isfinite(held_map)), held_map, x_map)

    def iteration(_, zu):
        z, u = zu
        x = x_map @ (shrink * (z - u))
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
