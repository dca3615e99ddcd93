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
from mujoco import mjx

from jaxloco.dynamics import se3
from jaxloco.dynamics.jacobians import screw_axes, tree_masks


def _body_jacobians(m: mjx.Model, d: mjx.Data):
    """Per body: angular ``(nbody, 3, nv)`` and CoM-point ``(nbody, 3, nv)`` Jacobians."""
    _, supports = tree_masks(m)
    s = screw_axes(m, d)
    mask = jnp.asarray(supports, s.dtype)  # (nbody, nv)
    s_b = s[None] * mask[:, :, None]  # (nbody, nv, 6)
    jac_w = jnp.swapaxes(s_b[..., :3], 1, 2)
    jac_v = jnp.swapaxes(s_b[..., 3:] + jnp.cross(s_b[..., :3], d.xipos[:, None, :]), 1, 2)
    return jac_w, jac_v


def body_world_inertia(m: mjx.Model, d: mjx.Data):
    """``(nbody, 3, 3)`` rotational inertia of each body about its CoM, world axes."""
    return jnp.einsum("bij,bj,bkj->bik", d.ximat, m.body_inertia, d.ximat)


def centre_of_mass(m: mjx.Model, d: mjx.Data):
    return m.body_mass @ d.xipos / jnp.sum(m.body_mass)


def centroidal_momentum_matrix(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """``J_cm`` (6, nv): rows ``[angular momentum about the CoM; linear momentum]``."""
    jac_w, jac_v = _body_jacobians(m, d)
    inertia = body_world_inertia(m, d)
    r = d.xipos - centre_of_mass(m, d)
    angular = jnp.einsum("bij,bjn->in", inertia, jac_w) + jnp.einsum(
        "b,bij,bjn->in", m.body_mass, se3.hat(r), jac_v
    )
    linear = jnp.einsum("b,bin->in", m.body_mass, jac_v)
    return jnp.concatenate([angular, linear], axis=0)


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


def centroidal_bias(jcm, mass_matrix, coriolis, mass_cholesky=None) -> jax.Array:
    """Eq. 31: ``Jdot_cm qd = J_cm A^-1 b`` (exact for the momentum; see module doc).

    ``A`` is solved by Cholesky (it is symmetric positive definite); ``mass_cholesky``: its
    lower-triangular factor when the caller has it.
    """
    chol = jnp.linalg.cholesky(mass_matrix) if mass_cholesky is None else mass_cholesky
    return jcm @ jax.scipy.linalg.cho_solve((chol, True), coriolis)
