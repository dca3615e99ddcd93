"""Joint-space dynamics terms of Eq. 11, ``A qdd + b + g = U^T tau + J_r^T F_r``, from MJX.

MJX computes the mass matrix (composite rigid bodies) and the total bias force
``qfrc_bias = b + g`` (recursive Newton-Euler); nothing here re-implements them. The
gravity part is ``g = -M J_com^T gravity`` (each body's weight mapped through its CoM
Jacobian, summed), and ``b = qfrc_bias - g``: Coriolis and centrifugal forces alone.
"""

from __future__ import annotations

import jax
from flax import struct

from jaxloco.dynamics.jacobians import com_jacobian, smooth
from jaxloco.dynamics.quiet_mjx import mjx


@struct.dataclass
class JointSpaceTerms:
    mass_matrix: jax.Array
    """``A`` (nv, nv)."""
    coriolis: jax.Array
    """``b`` (nv,): Coriolis and centrifugal forces."""
    gravity: jax.Array
    """``g`` (nv,)."""


def joint_space_terms(
    m: mjx.Model,
    d: mjx.Data,
    smoothed: bool = False,
    com_jac: jax.Array | None = None,
    mass_matrix: jax.Array | None = None,
) -> JointSpaceTerms:
    """``A``, ``b`` and ``g`` at ``(d.qpos, d.qvel)``. ``smoothed``: :func:`smooth` was run.
    ``com_jac``: the (3, nv) CoM Jacobian when the caller has it (e.g. the linear rows of
    the centroidal momentum matrix over the total mass); ``mass_matrix``: ``A`` when the
    caller has it (e.g. from MuJoCo C, :mod:`.engine_terms`)."""
    d = d if smoothed else smooth(m, d)
    total_mass = m.body_mass.sum()
    com_jac = com_jacobian(m, d) if com_jac is None else com_jac
    gravity = -total_mass * (com_jac.T @ m.opt.gravity)
    return JointSpaceTerms(
        mass_matrix=mjx.full_m(m, d) if mass_matrix is None else mass_matrix,
        coriolis=d.qfrc_bias - gravity,
        gravity=gravity,
    )
