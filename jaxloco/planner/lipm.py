"""Analytic linear inverted pendulum (LIPM) on a piecewise-linear height surface.

Paper: Appendix A, Eq. 35-38 and 43. The CoM moves on the surface ``z = a (x - p) + b``
above a pivot (the stance foot) at horizontal position ``p``. With the leg force along the
pivot-CoM line and ``z'' = a x''``, the horizontal dynamics are exactly linear::

    x'' = g (x - p) / b,        omega = sqrt(g / b)

so ``omega`` depends only on ``b``, the surface height above the pivot, and the slope ``a``
changes only ``z(t)``. (The paper writes ``omega = sqrt(g / (a p_x + b))`` for the surface
``z = a x + b`` in absolute coordinates: the same height-above-pivot.) The lateral axis obeys
the same equation with the same ``omega``. "Piecewise" means each stance phase has its own
``(a, b)``: call these functions per segment.

Every function is elementwise over leading axes (no Python control flow on values), so it
works under ``jit``, ``vmap`` and ``grad``. Functions that can fail return a validity flag
together with a finite placeholder, never NaN: gradients stay finite too (the "double
where" pattern: unsafe arguments are replaced *before* the unsafe operation).
"""

from __future__ import annotations

import jax.numpy as jnp

# Arguments below this are treated as zero where a division or log would blow up.
_TINY = 1e-12


def omega(g, height):
    """Natural frequency ``sqrt(g / b)`` of the LIPM for a CoM height ``b`` above the pivot."""
    return jnp.sqrt(g / height)


def propagate(x0, xd0, pivot, w, t):
    """State after time ``t`` from ``(x0, xd0)`` about ``pivot`` (Eq. 35-36).

    ``x(t) = A e^{wt} + B e^{-wt} + p`` with ``A, B = ((x0 - p) +- xd0 / w) / 2``, written
    with cosh/sinh. Valid for any ``t`` (negative ``t`` runs the pendulum backwards).
    Returns ``(x, xd)``.
    """
    c = jnp.cosh(w * t)
    s = jnp.sinh(w * t)
    r0 = x0 - pivot
    return pivot + r0 * c + xd0 / w * s, r0 * w * s + xd0 * c


def propagate_by_growth(x0, xd0, pivot, w, growth):
    """:func:`propagate` with the growth factor ``e^{wt}`` given instead of ``t``.

    Eq. 38 gives ``e^{wt}`` directly as its log's argument, so cosh and sinh follow from
    one division instead of transcendental calls (the planner's hot path).
    """
    inv = 1.0 / growth
    c = 0.5 * (growth + inv)
    s = 0.5 * (growth - inv)
    r0 = x0 - pivot
    return pivot + r0 * c + xd0 / w * s, r0 * w * s + xd0 * c


def acceleration(x, pivot, w):
    """LIPM acceleration ``w^2 (x - p)``."""
    return w**2 * (x - pivot)


def orbital_energy(x, xd, pivot, w):
    """The conserved quantity ``xd^2 - w^2 (x - p)^2`` of Eq. 42-43.

    Positive: the CoM passes over the pivot with apex speed ``sqrt(E)``. Negative: it turns
    back before reaching the pivot (or, past the pivot, never had an apex).
    """
    return xd**2 - w**2 * (x - pivot) ** 2


def orbit_velocity(x, energy, pivot, w, sign=1.0):
    """Velocity at position ``x`` on the orbit of given energy (Eq. 43).

    Returns ``(xd, valid)``; ``valid`` is False where the orbit does not reach ``x``
    (negative radicand), and ``xd`` is then 0.
    """
    radicand = w**2 * (x - pivot) ** 2 + energy
    valid = radicand > 0.0
    xd = jnp.sign(sign) * jnp.sqrt(jnp.where(valid, radicand, 1.0))
    return jnp.where(valid, xd, 0.0), valid


def growth_between(x0, xd0, x1, xd1, pivot, w):
    """The growth factor ``e^{wt}`` between two states on one orbit (Eq. 37-38).

    ``(x1 - p + xd1 / w) / (x0 - p + xd0 / w)``; see :func:`time_between` for validity.
    Returns ``(growth, valid)`` with ``growth = 1`` where invalid.
    """
    num = w * (x1 - pivot) + xd1
    den = w * (x0 - pivot) + xd0
    valid = (num > _TINY) & (den > _TINY)
    return jnp.where(valid, num, 1.0) / jnp.where(valid, den, 1.0), valid


def time_between(x0, xd0, x1, xd1, pivot, w):
    """Time to go from ``(x0, xd0)`` to ``(x1, xd1)`` on one orbit about ``pivot`` (Eq. 38).

    ``t = ln((x1 - p + xd1 / w) / (x0 - p + xd0 / w)) / w``: the ratio of the unstable
    components ``2A``. Both must be positive (a forward-moving CoM); otherwise the log's
    argument is not positive, the target is unreachable going forward, and ``valid`` is False
    with ``t = 0``. The two states must lie on the same orbit; only the unstable component is
    used. Returns ``(t, valid)``.
    """
    growth, valid = growth_between(x0, xd0, x1, xd1, pivot, w)
    return jnp.where(valid, jnp.log(growth) / w, 0.0), valid


def apex_of(x, xd, pivot, w):
    """Time and speed at which the CoM next (or last) passes over ``pivot`` moving forward.

    The apex of a stance phase is where ``x = p`` and the sagittal speed is at its minimum,
    ``sqrt(E)``. For a CoM already past the pivot the returned time is negative (the apex
    was in the past: the state is projected back along its orbit). Valid only when the orbit
    crosses the pivot moving forward (``E > 0`` and ``xd > 0``). Returns
    ``(t_to_apex, xd_apex, valid)``.
    """
    t, v_apex, _, valid = apex_growth_of(x, xd, pivot, w)
    return t, v_apex, valid


def apex_growth_of(x, xd, pivot, w):
    """:func:`apex_of` plus the growth factor ``e^{wt}`` (for :func:`propagate_by_growth`).

    Returns ``(t_to_apex, xd_apex, growth, valid)``; ``growth = 1`` where invalid.
    """
    energy = orbital_energy(x, xd, pivot, w)
    valid = (energy > _TINY) & (xd > 0.0)
    v_apex = jnp.sqrt(jnp.where(valid, energy, 1.0))
    growth, g_valid = growth_between(x, xd, pivot, v_apex, pivot, w)
    valid = valid & g_valid
    growth = jnp.where(valid, growth, 1.0)
    return jnp.log(growth) / w, jnp.where(valid, v_apex, 0.0), growth, valid


def surface_height(x, xd, xdd, pivot, slope, height):
    """CoM height, vertical velocity and acceleration on ``z = a (x - p) + b``.

    Returns ``(z, zd, zdd)`` for horizontal ``(x, xd, xdd)``.
    """
    return slope * (x - pivot) + height, slope * xd, slope * xdd
