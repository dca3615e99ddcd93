"""Where and when a step must land, from the LIPM about the stance foot: the fallback
capture step (:func:`capture_step`) and the step timing adaptation's deadlines
(:func:`dcm_time_limit`, :func:`com_lead_time_limit`). All in the stance frame (local
``x`` along the heading, ``y`` towards the swing side)."""

from __future__ import annotations

import jax.numpy as jnp

from jaxloco.locomotion.gait_params import GaitParams
from jaxloco.planner import lipm


def capture_step(params: GaitParams, w, rel, vel, remaining):
    """The fallback footstep (local frame) for a CoM at ``rel``/``vel`` (local, (2,)) that
    lands in ``remaining`` s: the predicted capture point shifted by
    ``fallback_dcm_offset`` (see :class:`GaitParams`)."""
    pos, v = lipm.propagate(rel, vel, 0.0, w, remaining)
    capture = pos + v / w
    bx, by = params.fallback_dcm_offset
    return capture + jnp.asarray([-bx, by], rel.dtype)


def dcm_time_limit(params: GaitParams, w, rel, vel):
    """Time until the LIPM's lateral DCM (local ``rel``, ``vel``, (2,)) leaves
    ``params.max_lateral_dcm`` (0 when it is already out): about the stance foot the DCM
    moves as ``xi(t) = xi(0) exp(omega t)``."""
    xi = rel[1] + vel[1] / w
    inward, outward = params.max_lateral_dcm
    bound = jnp.where(xi >= 0, outward, inward)
    ratio = bound / jnp.maximum(jnp.abs(xi), 1e-9)
    return jnp.log(jnp.maximum(ratio, 1.0)) / w


def com_lead_time_limit(params: GaitParams, w, rel, vel):
    """Time until the LIPM's CoM (local ``rel``, ``vel``, (2,)) runs ``params.max_com_lead``
    ahead of the stance foot (0 when it is already out and leaving; a large number when it
    never gets there). With ``x(t) = A e^(omega t) + B e^(-omega t)`` the crossing is the
    larger root ``u = e^(omega t)`` of ``A u^2 - L u + B = 0``."""
    lead = params.max_com_lead
    a = 0.5 * (rel[0] + vel[0] / w)
    b = 0.5 * (rel[0] - vel[0] / w)
    disc = lead * lead - 4.0 * a * b
    # Safe operands, so the branches not taken give zero gradients, not 0 * inf = NaN.
    safe_a = jnp.where(a > 0, a, 1.0)
    root = jnp.sqrt(jnp.where(disc > 0, disc, 1.0))
    t = jnp.log(jnp.maximum((lead + root) / (2.0 * safe_a), 1.0)) / w
    # disc <= 0 with a > 0: the CoM stays beyond the bound; a <= 0: it never diverges forward.
    never = jnp.asarray(params.max_step_duration, rel.dtype)
    return jnp.where(a > 0, jnp.where(disc > 0, t, 0.0), never)
