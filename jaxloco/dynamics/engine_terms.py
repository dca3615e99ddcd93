"""A state's kinematics and dynamics as MuJoCo's C engine computed them.

On MuJoCo C the engine computes, for the state it is about to integrate, everything a
WBLC tick reads: the bodies' and sites' poses, the joints' axes, the composite inertias,
the bias forces and the mass matrix (``mj_step1``, or ``Batch.step(stage=mjSTAGE_VEL)``).
:class:`EngineTerms` carries those fields into a jitted controller, and
:func:`engine_data` puts them where MJX's own stages would (:func:`.jacobians.smooth`), so
the controller reads the same ``mjx.Data`` either way without running MJX's kinematics,
composite-inertia and Newton-Euler passes again: a smaller program (it compiles faster)
and a shorter tick. The MJX path stays for MJX rollouts and for gradients; both give the
same numbers to float round-off (the tests compare them).

``mj_step1`` followed by ``mj_step2`` is ``mj_step`` for the Euler and implicit
integrators (MuJoCo's documented split); RK4 has no such split.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco.dynamics.quiet_mjx import mjx


class EngineTerms(NamedTuple):
    """The position- and velocity-stage fields of one state, MjData's names and layouts.

    Numpy (one robot: no leading axis; a batch: a leading axis of robots) on the way in,
    JAX arrays inside a program. ``nbody``, ``njnt``, ``nsite``, ``nv``, ``nq`` are the
    model's sizes, ``nC`` its mass matrix's stored entries."""

    qpos: np.ndarray | jax.Array
    """(nq,) joint positions."""
    qvel: np.ndarray | jax.Array
    """(nv,) joint velocities."""
    xquat: np.ndarray | jax.Array
    """(nbody, 4) body orientations (w, x, y, z), world frame."""
    xmat: np.ndarray | jax.Array
    """(nbody, 9) body rotation matrices, row-major."""
    xipos: np.ndarray | jax.Array
    """(nbody, 3) body centres of mass, world frame (m)."""
    ximat: np.ndarray | jax.Array
    """(nbody, 9) body inertia frames, row-major."""
    xanchor: np.ndarray | jax.Array
    """(njnt, 3) joint anchors, world frame (m)."""
    xaxis: np.ndarray | jax.Array
    """(njnt, 3) joint axes, world frame."""
    site_xpos: np.ndarray | jax.Array
    """(nsite, 3) site positions, world frame (m)."""
    subtree_com: np.ndarray | jax.Array
    """(nbody, 3) centre of mass of each body's subtree (m)."""
    cdof: np.ndarray | jax.Array
    """(nv, 6) each dof's motion axis ``[angular; linear]`` at its tree's centre of mass."""
    crb: np.ndarray | jax.Array
    """(nbody, 10) composite rigid-body inertias at the same point (MuJoCo's 10-vectors)."""
    qfrc_bias: np.ndarray | jax.Array
    """(nv,) bias forces ``b + g``: Coriolis, centrifugal and gravity (N, N m)."""
    M: np.ndarray | jax.Array
    """(nC,) the mass matrix's lower triangle in MuJoCo's compressed rows (``M_rowadr``,
    ``M_rownnz``, ``M_colind``); :func:`dense_mass_matrix` unpacks it."""


ENGINE_FIELDS = EngineTerms._fields
"""The MjData fields :class:`EngineTerms` holds, in its order."""


def engine_terms(data: mujoco.MjData) -> EngineTerms:
    """Copies of ``data``'s fields, after ``mj_step1`` (or ``mj_forward``) on its state."""
    return EngineTerms(*(np.array(getattr(data, name)) for name in ENGINE_FIELDS))


def bind_engine_terms(batch) -> EngineTerms:
    """The live ``(nsim, ...)`` arrays of a ``mujoco.batch.Batch``'s fields: current after
    ``batch.step(..., stage=mujoco.mjtStage.mjSTAGE_VEL)`` (or ``batch.forward``)."""
    return EngineTerms(*(batch.bind(name) for name in ENGINE_FIELDS))


SAME_DYNAMICS_FIELDS = (
    "body_parentid",
    "jnt_type",
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_iquat",
    "body_pos",
    "body_quat",
    "jnt_pos",
    "jnt_axis",
    "dof_armature",
    "site_bodyid",
    "site_pos",
    "site_quat",
)
"""Model fields that decide the terms a controller reads: they must agree between the
controller's model and the simulated one."""


def check_same_dynamics(mx: mjx.Model, model: mujoco.MjModel, rtol: float = 1e-6) -> None:
    """Raise ``ValueError`` unless the simulated ``model`` has the kinematics and inertias
    of the controller's ``mx`` (the engine's terms then are the controller's own); a
    controller of another model (a mass error on purpose, say) must compute its own."""
    for name in SAME_DYNAMICS_FIELDS:
        ours, theirs = np.asarray(getattr(mx, name)), np.asarray(getattr(model, name))
        if ours.shape != theirs.shape or not np.allclose(ours, theirs, rtol=rtol, atol=1e-9):
            raise ValueError(
                f"the simulated model's {name} differs from the controller's: the engine's "
                "terms would be another robot's; let the controller compute its own "
                "(simulate_walk(engine=False), or a controller that ignores engine=)"
            )


def _dense_index(rownnz, rowadr, colind) -> np.ndarray:
    """``(nv, nv)`` index into ``M`` of every entry of the full matrix (-1: zero)."""
    nv = len(rownnz)
    index = np.full((nv, nv), -1, np.int32)
    for i in range(nv):
        for k in range(int(rowadr[i]), int(rowadr[i]) + int(rownnz[i])):
            j = int(colind[k])
            index[i, j] = index[j, i] = k
    return index


def dense_mass_matrix(mx: mjx.Model, compressed) -> jax.Array:
    """The full ``(nv, nv)`` mass matrix from its compressed rows (``EngineTerms.M``)."""
    index = _dense_index(mx.M_rownnz, mx.M_rowadr, mx.M_colind)
    return jnp.where(index >= 0, compressed[np.maximum(index, 0)], 0.0)


def engine_data(mx: mjx.Model, terms: EngineTerms) -> mjx.Data:
    """An ``mjx.Data`` holding ``terms`` where :func:`.jacobians.smooth` would put them
    (what the WBLC's snapshot reads); fields the terms do not carry are MJX's zeros."""
    dtype = jnp.asarray(terms.qvel).dtype
    t = jax.tree.map(lambda x: jnp.asarray(x, dtype), terms)
    d = mjx.make_data(mx).replace(
        qpos=t.qpos,
        qvel=t.qvel,
        xquat=t.xquat,
        xmat=t.xmat.reshape(*t.xmat.shape[:-1], 3, 3),
        xipos=t.xipos,
        ximat=t.ximat.reshape(*t.ximat.shape[:-1], 3, 3),
        xanchor=t.xanchor,
        xaxis=t.xaxis,
        site_xpos=t.site_xpos,
        subtree_com=t.subtree_com,
        cdof=t.cdof,
        qfrc_bias=t.qfrc_bias,
    )
    # MJX 3.x keeps the composite inertias with its JAX implementation's fields.
    return d.replace(_impl=d._impl.replace(crb=t.crb))
