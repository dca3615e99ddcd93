"""Centroidal momentum: the matrix ``J_cm`` (= A_G), and Eq. 31's ``Jdot_cm qd``.

``h = J_cm qd = [k; l]``: angular momentum about the centre of mass and linear momentum,
summed over bodies (``k = sum_b I_b w_b + m_b (c_b - c) x v_b``, ``l = sum_b m_b v_b``).

**Eq. 31, ``Jdot_cm qd = J_cm A^-1 b``.** The paper states it without proof. It holds
*exactly for the momentum* ``h`` (both parts), with ``b`` the Coriolis/centrifugal forces
alone (gravity in ``g``): actuator torques are internal, so ``J_cm A^-1 U^T = 0``, and a
system with no external force keeps its momentum, ``0 = hdot = J_cm qdd + Jdot_cm qd`` with
``qdd = -A^-1 b``. It does **not** hold for an averaged velocity such as
``I_G^-1 h`` (the "centroidal velocity"): its rate has the extra term ``d/dt(I_G^-1) h``.
The tests check both statements against ``jax.jvp``; the controller uses
:func:`centroidal_bias` (exact) for the momentum task.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxloco.dynamics import se3
from jaxloco.dynamics.quiet_mjx import mjx


def body_world_inertia(m: mjx.Model, d: mjx.Data):
    """``(nbody, 3, 3)`` rotational inertia of each body about its CoM, world axes."""
    return jnp.einsum("bij,bj,bkj->bik", d.ximat, m.body_inertia, d.ximat)


def centre_of_mass(m: mjx.Model, d: mjx.Data):
    return m.body_mass @ d.xipos / jnp.sum(m.body_mass)


def spatial_inertia_times(inertia, motion):
    """Momentum ``[angular; linear]`` (..., 6) of a rigid inertia moving with ``motion``
    ``[w; v]`` (..., 6), both at one point: MuJoCo's 10-vector ``inertia`` (..., 10) holds
    the rotational inertia about that point ``(xx, yy, zz, xy, xz, yz)``, the first moment
    ``m c`` (c: the centre of mass from the point) and the mass ``m``."""
    w, v = motion[..., :3], motion[..., 3:]
    xx, yy, zz, xy, xz, yz = (inertia[..., k] for k in range(6))
    first_moment, mass = inertia[..., 6:9], inertia[..., 9:10]
    rotational = jnp.stack(
        [
            xx * w[..., 0] + xy * w[..., 1] + xz * w[..., 2],
            xy * w[..., 0] + yy * w[..., 1] + yz * w[..., 2],
            xz * w[..., 0] + yz * w[..., 1] + zz * w[..., 2],
        ],
        -1,
    )
    angular = rotational + jnp.cross(first_moment, v)
    linear = mass * v - jnp.cross(first_moment, w)
    return jnp.concatenate([angular, linear], -1)


def centroidal_momentum_matrix(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """``J_cm`` (6, nv): rows ``[angular momentum about the CoM; linear momentum]``.

    Column ``i`` is the momentum of the bodies dof ``i`` moves, moving with that dof alone:
    the composite rigid-body inertia of its subtree (MJX's ``crb``) times its motion axis
    (``cdof``). MJX keeps both at the centre of mass of the dof's kinematic tree, with world
    axes; the angular rows are shifted from there to the whole model's centre of mass (a
    no-op for a single tree such as a humanoid). Needs :func:`jacobians.smooth` (``crb``).
    """
    bodies = np.asarray(m.dof_bodyid)
    # MJX 3.x keeps the composite inertias with its JAX implementation's fields.
    composite = d._impl.crb[bodies]
    per_dof = spatial_inertia_times(composite, d.cdof)  # (nv, 6) at each tree's CoM
    roots = np.asarray(m.body_rootid)[bodies]
    offset = d.subtree_com[roots] - centre_of_mass(m, d)  # tree CoM from the whole CoM
    angular = per_dof[:, :3] + jnp.cross(offset, per_dof[:, 3:])
    return jnp.concatenate([angular, per_dof[:, 3:]], axis=1).T


def centroidal_inertia(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """The locked (composite) inertia ``I_G`` (6, 6) about the CoM: ``diag(I, M 1)``."""
    r = d.xipos - centre_of_mass(m, d)
    rx = se3.hat(r)
    rotational = jnp.sum(body_world_inertia(m, d), 0) - jnp.einsum(
        "b,bij,bjk->ik", m.body_mass, rx, rx
    )
    total = jnp.sum(m.body_mass)
    zeros = jnp.zeros((3, 3), r.dtype)
    return jnp.block([[rotational, zeros], [zeros, total * jnp.eye(3, dtype=r.dtype)]])


def centroidal_bias(
    jcm, mass_matrix, coriolis, mass_cholesky=None, mass_cholesky_inverse=None
) -> jax.Array:
    """Eq. 31: ``Jdot_cm qd = J_cm A^-1 b`` (exact for the momentum; see module doc).

    ``A`` is solved by Cholesky (it is symmetric positive definite); ``mass_cholesky``: its
    lower-triangular factor when the caller has it; ``mass_cholesky_inverse``: that
    factor's inverse ``L^-1``, when the caller has it (then ``A^-1 b = L^-T L^-1 b`` by
    products, no solve).
    """
    if mass_cholesky_inverse is not None:
        return jcm @ (mass_cholesky_inverse.T @ (mass_cholesky_inverse @ coriolis))
    chol = jnp.linalg.cholesky(mass_matrix) if mass_cholesky is None else mass_cholesky
    return jcm @ jax.scipy.linalg.cho_solve((chol, True), coriolis)
