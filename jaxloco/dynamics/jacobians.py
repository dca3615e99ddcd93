"""Task Jacobians and their ``J-dot q-dot`` terms on MJX data, by the Lie-group construction.

Paper Section IV-A (Eq. 21-29). Every dof ``i`` has a screw axis ``S_i = [w_i; v_i]`` in
world coordinates at the world origin, built from MJX's kinematics (hinge: axis ``a``
through anchor ``x``, ``S = [a; x x a]``; free joint: world translations ``[0; e_k]`` and
rotations about the body's own axes through its origin). A body's spatial twist is
``V_b = sum_i S_i qd_i`` over the dofs supporting it (Eq. 26), and its Jacobian has those
screw axes as columns (Eq. 27). A screw axis moves with everything before it in the tree,
so ``d/dt S_i = ad_{V_i^-} S_i``, where ``V_i^-`` is the twist of the dofs preceding ``i``
(Eq. 29; MuJoCo's ``dof_parentid`` gives that order; the three rotations of a ball or free
joint all take the twist from before that joint's rotation). Hence::

    Jdot_b qd = sum_{i supports b} ad_{V_i^-} S_i qd_i          (spatial, 6)
    Jdot_p qd = a_v + a_w x p + w_b x v_p                       (point p on body b)

with ``[a_w; a_v] = Jdot_b qd``. (For a multi-dof joint the axes also turn with the joint's
own rotation; that term, ``w x w``, vanishes in ``Jdot qd``, which is what controllers need.)

Frame Jacobians are ``(6, nv)`` with rows ``[angular; linear]`` (the paper's ``[w, v]``);
point and CoM Jacobians ``(3, nv)``. Call :func:`smooth` (or ``mjx.forward``) first.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco.dynamics import se3
from jaxloco.dynamics.quiet_mjx import mjx


def smooth(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """Position and velocity stages MJX needs for the quantities here (no collisions)."""
    d = mjx.kinematics(m, d)
    d = mjx.com_pos(m, d)
    d = mjx.crb(m, d)
    d = mjx.com_vel(m, d)
    return mjx.rne(m, d)


@functools.lru_cache(maxsize=32)
def _tree_masks(
    dof_parentid: tuple, dof_bodyid: tuple, body_parentid: tuple, rotation_groups: tuple
):
    """Static masks: ``before[i, j]``: dof j precedes dof i in the tree (for the 3 rotations
    of a ball or free joint, the twist before that joint's rotation: their own mutual terms
    cancel in ``Jdot qd`` only as a whole); ``supports[b, i]``: dof i moves body b."""
    nv, nbody = len(dof_parentid), len(body_parentid)
    before = np.zeros((nv, nv), bool)
    for i in range(nv):
        j = dof_parentid[i]
        while j >= 0:
            before[i, j] = True
            j = dof_parentid[j]
    for group in rotation_groups:
        for i in group:
            for j in group:
                before[i, j] = False
    supports = np.zeros((nbody, nv), bool)
    for i in range(nv):
        b_dof = dof_bodyid[i]
        for b in range(nbody):
            a = b
            while a > 0 and a != b_dof:
                a = body_parentid[a]
            supports[b, i] = a == b_dof and b_dof > 0
    return before, supports


def tree_masks(m: mjx.Model):
    groups = []
    for j in range(m.njnt):
        adr, typ = int(m.jnt_dofadr[j]), int(m.jnt_type[j])
        if typ == mujoco.mjtJoint.mjJNT_FREE:
            groups.append((adr + 3, adr + 4, adr + 5))
        elif typ == mujoco.mjtJoint.mjJNT_BALL:
            groups.append((adr, adr + 1, adr + 2))
    return _tree_masks(
        tuple(int(x) for x in m.dof_parentid),
        tuple(int(x) for x in m.dof_bodyid),
        tuple(int(x) for x in m.body_parentid),
        tuple(groups),
    )


@functools.lru_cache(maxsize=32)
def _screw_layout(jnt_type: tuple, jnt_dofadr: tuple, jnt_bodyid: tuple):
    """Static gathers that build every dof's screw axis at once (see :func:`screw_axes`):
    per dof, the row of ``[xaxis; the rotating bodies' xmat columns; I3]`` holding its
    direction ``a``, its joint (the anchor ``x``), and whether its axis turns (``[a; x x a]``)
    or translates (``[0; a]``)."""
    dofs = {mujoco.mjtJoint.mjJNT_FREE: 6, mujoco.mjtJoint.mjJNT_BALL: 3}
    nv = sum(dofs.get(t, 1) for t in jnt_type)
    njnt = len(jnt_type)
    rot_bodies = []  # bodies of ball and free joints, whose xmat columns are axes
    direction = np.zeros(nv, np.int32)
    joint = np.zeros(nv, np.int32)
    turns = np.zeros(nv, bool)
    for j, (typ, adr, body) in enumerate(zip(jnt_type, jnt_dofadr, jnt_bodyid, strict=True)):
        if typ in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            direction[adr], joint[adr] = j, j
            turns[adr] = typ == mujoco.mjtJoint.mjJNT_HINGE
            continue
        start = adr
        if typ == mujoco.mjtJoint.mjJNT_FREE:  # world translations first
            direction[adr : adr + 3] = -3 + np.arange(3)  # the last three rows: I3
            joint[adr : adr + 3] = j
            start = adr + 3
        # rotations about the body's own axes (qvel is local), through the joint's anchor
        direction[start : start + 3] = njnt + 3 * len(rot_bodies) + np.arange(3)
        joint[start : start + 3] = j
        turns[start : start + 3] = True
        rot_bodies.append(body)
    return np.asarray(rot_bodies, np.int32), direction, joint, turns


def screw_axes(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """``(nv, 6)`` screw axes ``[w; v]`` of every dof, world frame at the world origin."""
    rot_bodies, direction, joint, turns = _screw_layout(
        tuple(int(x) for x in m.jnt_type),
        tuple(int(x) for x in m.jnt_dofadr),
        tuple(int(x) for x in m.jnt_bodyid),
    )
    dtype = d.xanchor.dtype
    columns = jnp.swapaxes(d.xmat[rot_bodies], 1, 2).reshape(-1, 3)  # each body's x, y, z axes
    table = jnp.concatenate([d.xaxis, columns, jnp.eye(3, dtype=dtype)])
    axis = table[direction % len(table)]
    anchor = d.xanchor[joint]
    turning = jnp.asarray(turns, dtype)[:, None]
    angular = axis * turning
    linear = jnp.cross(anchor, axis) * turning + axis * (1.0 - turning)
    return jnp.concatenate([angular, linear], axis=1)


class BodyMotion(NamedTuple):
    """Every body's velocity terms, in world coordinates at the world origin."""

    twists: jax.Array
    """(nbody, 6) spatial twists ``[angular; linear]``."""
    bias_accelerations: jax.Array
    """(nbody, 6) velocity-product accelerations ``Jdot_b qd``."""


def body_motion(m: mjx.Model, d: mjx.Data) -> BodyMotion:
    """Per body: spatial twists ``(nbody, 6)`` and velocity-product accelerations
    ``Jdot_b qd`` ``(nbody, 6)``, both in world coordinates at the world origin."""
    before, supports = tree_masks(m)
    s = screw_axes(m, d)
    s_qd = s * d.qvel[:, None]
    v_before = jnp.asarray(before, s.dtype) @ s_qd  # twist preceding each dof
    terms = se3.ad_apply(v_before, s_qd)  # ad_{V_i^-} S_i qd_i
    sup = jnp.asarray(supports, s.dtype)
    return BodyMotion(sup @ s_qd, sup @ terms)


def frame_jacobian_spatial(m: mjx.Model, d: mjx.Data, body_id: int) -> jax.Array:
    """``(6, nv)`` spatial Jacobian of a body (columns: the supporting screw axes)."""
    _, supports = tree_masks(m)
    return (screw_axes(m, d) * jnp.asarray(supports[body_id], d.qvel.dtype)[:, None]).T


def point_jacobian(m: mjx.Model, d: mjx.Data, point, body_id: int) -> jax.Array:
    """``(3, nv)`` Jacobian of a world point moving with ``body_id``."""
    js = frame_jacobian_spatial(m, d, body_id)
    return js[3:] + jnp.cross(js[:3].T, point).T


def frame_jacobian(m: mjx.Model, d: mjx.Data, point, body_id: int) -> jax.Array:
    """``(6, nv)`` Jacobian ``[angular; linear at point]`` of a frame on ``body_id``."""
    js = frame_jacobian_spatial(m, d, body_id)
    return jnp.concatenate([js[:3], js[3:] + jnp.cross(js[:3].T, point).T], axis=0)


def point_jdot_qdot(m: mjx.Model, d: mjx.Data, point, body_id: int, motion=None) -> jax.Array:
    """``Jdot qd`` (3,) of a world point moving with ``body_id``.

    ``motion``: the output of :func:`body_motion`, to share it between tasks.
    """
    twists, accs = body_motion(m, d) if motion is None else motion
    twist, acc = twists[body_id], accs[body_id]
    v_p = se3.point_velocity(twist, point)
    return acc[3:] + jnp.cross(acc[:3], point) + jnp.cross(twist[:3], v_p)


def frame_jdot_qdot(m: mjx.Model, d: mjx.Data, point, body_id: int, motion=None) -> jax.Array:
    """``Jdot qd`` (6,) ``[angular; linear at point]`` of a frame on ``body_id``."""
    twists, accs = body_motion(m, d) if motion is None else motion
    linear = point_jdot_qdot(m, d, point, body_id, (twists, accs))
    return jnp.concatenate([accs[body_id][:3], linear])


def site_frame(m: mjx.Model, d: mjx.Data, site_id: int):
    """``(position, body_id)`` of a site (for the frame/point functions)."""
    return d.site_xpos[site_id], int(m.site_bodyid[site_id])


def com_jacobian(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """``(3, nv)`` Jacobian of the whole-body centre of mass."""
    masses = m.body_mass
    jacs = jax.vmap(lambda p, b: _point_jacobian_all(m, d, p, b))(d.xipos, jnp.arange(m.nbody))
    return jnp.einsum("b,bij->ij", masses, jacs) / jnp.sum(masses)


def com_jdot_qdot(m: mjx.Model, d: mjx.Data, motion=None) -> jax.Array:
    """``Jdot_com qd`` (3,): the CoM acceleration due to velocities alone."""
    twists, accs = body_motion(m, d) if motion is None else motion
    v_c = se3.point_velocity(twists, d.xipos)
    per_body = accs[:, 3:] + jnp.cross(accs[:, :3], d.xipos) + jnp.cross(twists[:, :3], v_c)
    return m.body_mass @ per_body / jnp.sum(m.body_mass)


def _point_jacobian_all(m, d, point, body_id):
    """point_jacobian with a traced body index (for vmap over bodies)."""
    _, supports = tree_masks(m)
    mask = jnp.asarray(supports, d.qvel.dtype)[body_id]
    s = screw_axes(m, d) * mask[:, None]
    return (s[:, 3:] + jnp.cross(s[:, :3], point)).T
