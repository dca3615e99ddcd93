"""The analytic LIPM against numerical integration (scipy, float64)."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from jaxloco.planner import lipm

G, H = 9.81, 1.005294
W = float(np.sqrt(G / H))
RNG = np.random.default_rng(0)


def integrate_lipm(x0, xd0, pivot, w, t):
    sol = solve_ivp(
        lambda _, s: [s[1], w**2 * (s[0] - pivot)],
        (0.0, t),
        [x0, xd0],
        method="DOP853",
        rtol=1e-13,
        atol=1e-13,
    )
    return sol.y[:, -1]


@pytest.mark.parametrize("case", range(20))
def test_propagate_matches_integration(case):
    x0, xd0, pivot = RNG.uniform(-0.3, 0.3, 3)
    t = RNG.uniform(-0.8, 0.8)
    x, xd = lipm.propagate(x0, xd0, pivot, W, t)
    ref = integrate_lipm(x0, xd0, pivot, W, t)
    np.testing.assert_allclose([x, xd], ref, atol=1e-10)


def test_omega_and_acceleration():
    assert float(lipm.omega(G, H)) == pytest.approx(W)
    assert float(lipm.acceleration(0.1, 0.02, W)) == pytest.approx(W**2 * 0.08)


def test_energy_is_conserved_and_orbit_velocity_matches():
    x0, xd0, pivot = 0.05, 0.3, 0.0
    e0 = lipm.orbital_energy(x0, xd0, pivot, W)
    ts = jnp.linspace(-0.5, 0.5, 11)
    x, xd = lipm.propagate(x0, xd0, pivot, W, ts)
    np.testing.assert_allclose(lipm.orbital_energy(x, xd, pivot, W), e0, atol=1e-12)
    v, ok = lipm.orbit_velocity(x, e0, pivot, W, 1.0)
    assert bool(jnp.all(ok))
    np.testing.assert_allclose(v, xd, atol=1e-12)
    # An orbit that turns back before the pivot does not reach it.
    v, ok = lipm.orbit_velocity(0.0, -0.01, 0.0, W)
    assert not bool(ok) and float(v) == 0.0


def test_time_between_inverts_propagate():
    x0, xd0, pivot = -0.1, 0.5, 0.02
    for t in (0.05, 0.3, 0.7):
        x1, xd1 = lipm.propagate(x0, xd0, pivot, W, t)
        t_back, ok = lipm.time_between(x0, xd0, x1, xd1, pivot, W)
        assert bool(ok)
        assert float(t_back) == pytest.approx(t, abs=1e-12)


def test_time_between_flags_nonpositive_log_argument():
    # Moving backwards: the unstable component is negative, Eq. 38's log argument is not > 0.
    t, ok = lipm.time_between(0.0, -0.3, 0.1, 0.5, 0.0, W)
    assert not bool(ok) and float(t) == 0.0


def test_apex_of():
    # Before the pivot and past it: the apex lies ahead (t > 0) and behind (t < 0).
    for x0, sign in ((-0.05, 1), (0.05, -1)):
        t, v, ok = lipm.apex_of(x0, 0.4, 0.0, W)
        assert bool(ok) and np.sign(float(t)) == sign
        x, xd = lipm.propagate(x0, 0.4, 0.0, W, t)
        assert float(x) == pytest.approx(0.0, abs=1e-12)
        assert float(xd) == pytest.approx(float(v), abs=1e-12)
    # Too slow to pass over the pivot, or moving backwards: no forward apex.
    assert not bool(lipm.apex_of(-0.2, 0.3, 0.0, W)[2])
    assert not bool(lipm.apex_of(0.0, -0.3, 0.0, W)[2])


@pytest.mark.parametrize("slope", [-0.3, 0.0, 0.25])
def test_slope_changes_height_not_horizontal_motion(slope):
    """A point mass on z = a (x - p) + b with the leg force along pivot->CoM.

    Integrated in its general form x'' = (x - p)(g + z'') / z with z'' = a x'' solved at each
    evaluation: the horizontal motion must match the LIPM with omega = sqrt(g / b).
    """
    b, pivot, x0, xd0, t_end = H, 0.0, -0.08, 0.45, 0.6

    def rhs(_, s):
        x, xd = s
        z = slope * (x - pivot) + b
        # x'' (1 - a (x - p) / z) = g (x - p) / z
        xdd = G * (x - pivot) / z / (1.0 - slope * (x - pivot) / z)
        return [xd, xdd]

    sol = solve_ivp(rhs, (0, t_end), [x0, xd0], method="DOP853", rtol=1e-13, atol=1e-13)
    x, xd = lipm.propagate(x0, xd0, pivot, lipm.omega(G, b), t_end)
    np.testing.assert_allclose([x, xd], sol.y[:, -1], atol=1e-10)
    z, zd, zdd = lipm.surface_height(x, xd, lipm.acceleration(x, pivot, W), pivot, slope, b)
    assert float(z) == pytest.approx(slope * (float(x) - pivot) + b)
    assert float(zd) == pytest.approx(slope * float(xd))
    assert float(zdd) == pytest.approx(slope * W**2 * (float(x) - pivot))
