"""WBLC's whole-body limit stage against a trusted QP solver (quadprog, float64): the
smallest change of the torques, in units of each limit, that brings them within their
limits with the held rows' accelerations kept."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

quadprog = pytest.importorskip("quadprog")

from jaxloco.control.torque_limits import TorqueLimitParams, limit_torques  # noqa: E402

NV, NU, HELD = 35, 29, 12  # a G1's size: floating base, 29 joints, two feet of 6 rows


def random_problem(rng, single_support=False):
    """A mass matrix, a floating base of 6 unactuated dofs, limits from a wrist's 5 N m to
    a knee's 140 N m, requested torques of which about a third exceed their limits, and
    one or two held feet."""
    root = rng.normal(size=(NV, NV))
    mass = root @ root.T / NV + 0.5 * np.eye(NV)
    selection = np.zeros((NU, NV))
    selection[np.arange(NU), np.arange(6, 6 + NU)] = 1.0
    limits = rng.uniform(5.0, 140.0, NU)
    torques = limits * rng.uniform(-1.4, 1.4, NU)
    held = rng.normal(size=(HELD, NV))
    if single_support:
        held[6:] = 0.0  # a foot out of contact: its rows are off
    return mass, selection, limits, torques, held


def quadprog_change(mass, selection, limits, torques, held):
    """The scaled change ``x = dtau / limit`` by quadprog: ``min |x|^2`` with the held
    rows' accelerations kept and every torque within its limit."""
    rows = held @ np.linalg.solve(mass, selection.T) * limits[None, :]
    rows = rows[np.abs(rows).sum(axis=1) > 0]
    lower, upper = (-limits - torques) / limits, (limits - torques) / limits
    constraints = np.concatenate([rows.T, np.eye(NU), -np.eye(NU)], axis=1)
    bounds = np.concatenate([np.zeros(rows.shape[0]), lower, -upper])
    return quadprog.solve_qp(np.eye(NU), np.zeros(NU), constraints, bounds, rows.shape[0])[0]


def solve(mass, selection, limits, torques, held, params=None):
    params = TorqueLimitParams() if params is None else params
    cholesky_inverse = np.linalg.inv(np.linalg.cholesky(mass))
    args = [jnp.asarray(x) for x in (torques, limits, selection, cholesky_inverse, held)]
    return jax.jit(limit_torques, static_argnums=5)(*args, params)


def test_limit_stage_matches_quadprog_on_random_problems():
    """100 random single and double support problems at the default 60 iterations: every
    torque within its limit exactly; the objective within 1e-4 relative of quadprog's at
    the median and 2e-3 at the 80th percentile; the held rows kept to 1e-3 of their scale
    at the median."""
    rng = np.random.default_rng(0)
    errors, residuals = [], []
    for trial in range(100):
        mass, selection, limits, torques, held = random_problem(rng, trial % 3 == 0)
        sol = solve(mass, selection, limits, torques, held)
        reference = quadprog_change(mass, selection, limits, torques, held)
        change = np.asarray(sol.torque_change) / limits
        assert np.all(np.abs(np.asarray(sol.torques)) <= limits * (1 + 1e-12))
        np.testing.assert_allclose(sol.torques, torques + np.asarray(sol.torque_change))
        assert bool(sol.active)
        best = reference @ reference
        errors.append(abs(change @ change - best) / best)
        rows = held @ np.linalg.solve(mass, selection.T) * limits[None, :]
        residuals.append(float(sol.held_residual) / np.abs(rows).max())
        # The reported acceleration change is the torque change through the dynamics.
        np.testing.assert_allclose(
            sol.acceleration_change,
            np.linalg.solve(mass, selection.T @ np.asarray(sol.torque_change)),
            atol=1e-9,
        )
    assert np.median(errors) < 1e-4
    assert np.quantile(errors, 0.8) < 2e-3
    assert np.median(residuals) < 1e-3


def test_torques_within_their_limits_are_left_alone():
    rng = np.random.default_rng(1)
    mass, selection, limits, _, held = random_problem(rng)
    torques = limits * rng.uniform(-0.99, 0.99, NU)
    sol = solve(mass, selection, limits, torques, held)
    np.testing.assert_array_equal(sol.torques, torques)
    assert not bool(sol.active)
    assert float(sol.held_residual) == 0.0
    assert np.all(np.asarray(sol.acceleration_change) == 0.0)


def test_unlimited_actuators_and_no_held_rows():
    """An actuator without a limit (inf) is never changed; with no held rows the change
    is the clip, each torque to its own limit."""
    rng = np.random.default_rng(2)
    mass, selection, limits, torques, _ = random_problem(rng)
    limits[0] = np.inf
    torques[0] = 1e4
    sol = solve(mass, selection, limits, torques, np.zeros((0, NV)))
    np.testing.assert_allclose(sol.torques, np.clip(torques, -limits, limits), atol=1e-9)
    assert float(sol.torques[0]) == 1e4
    # Both feet out of contact: their rows are zero, and hold nothing.
    airborne = solve(mass, selection, limits, torques, np.zeros((HELD, NV)))
    np.testing.assert_allclose(airborne.torques, sol.torques, atol=1e-9)
    assert float(airborne.held_residual) == 0.0


def test_held_rows_that_cannot_be_factored_hold_nothing_instead_of_nan():
    """Rows the Cholesky factorisation cannot take (here non-finite) leave the torques
    finite and within their limits."""
    rng = np.random.default_rng(3)
    mass, selection, limits, torques, held = random_problem(rng)
    held[0, 0] = np.inf
    sol = solve(mass, selection, limits, torques, held)
    assert np.all(np.isfinite(np.asarray(sol.torques)))
    assert np.all(np.abs(np.asarray(sol.torques)) <= limits * (1 + 1e-12))


def test_limit_stage_settings_are_checked_by_name():
    with pytest.raises(ValueError, match="iterations"):
        TorqueLimitParams(iterations=0)
    with pytest.raises(ValueError, match="rho"):
        TorqueLimitParams(rho=-1.0)
    with pytest.raises(ValueError, match="held_rtol"):
        TorqueLimitParams(held_rtol=2.0)
