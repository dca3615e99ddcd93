"""The contact-force QP against a trusted QP solver (quadprog, float64): the per-point
projection, the closed-form feasibility test, and the ADMM solve."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

quadprog = pytest.importorskip("quadprog")

from jaxloco.control.force_qp import (  # noqa: E402
    ForceQPParams,
    net_force_feasible,
    project_point,
    solve_contact_forces,
    zero_warm_start,
)

CORNERS = np.array([[0.119, 0.05], [0.119, -0.05], [-0.081, 0.05], [-0.081, -0.05]])


def contact_problem(rng, max_accel=3.0):
    double = rng.random() < 0.5
    points = []
    for side in (1, -1):
        yaw = rng.uniform(-0.5, 0.5)
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        base = np.array([rng.uniform(-0.2, 0.2), side * rng.uniform(0.1, 0.2)])
        points += [[*(base + rot @ c), 0.0] for c in CORNERS]
    points = np.array(points)
    contact = np.ones(8, bool) if double else np.r_[np.ones(4, bool), np.zeros(4, bool)]
    support = points[contact].mean(0)
    com = np.r_[support[:2] + rng.uniform(-0.05, 0.05, 2), rng.uniform(0.9, 1.1)]
    accel = np.r_[rng.uniform(-max_accel, max_accel, 2), rng.uniform(-2, 2)]
    f_lin = 135.9 * (accel + [0, 0, 9.81])
    f_ang = rng.uniform(-50, 50, 3)
    return points, contact, com, f_lin, f_ang


def eq14_for_quadprog(points, idx, com, f_lin, f_ang, mu=0.65):
    """Eq. 14 over the points ``idx`` for quadprog, in newtons: Hessian, linear term, and
    constraint rows with their right-hand sides (the net force first, as equalities)."""
    k = len(idx)

    def skew(r):
        return np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])

    W = np.hstack([skew(r) for r in points[idx] - com])
    G = 2 * (np.diag(np.tile([1.0, 1.0, 0.5], k)) + 5000 * W.T @ W)
    a = 2 * 5000 * W.T @ f_ang
    rows, rhs = [np.tile(np.eye(3), (1, k))], [f_lin]
    for i in range(k):
        for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            r = np.zeros(3 * k)
            r[3 * i], r[3 * i + 1], r[3 * i + 2] = -sx, -sy, mu
            rows.append(r[None])
            rhs.append([0.0])
        for j, (lo, hi) in enumerate(((-1000, 1000), (-1000, 1000), (5, 3000))):
            e = np.zeros(3 * k)
            e[3 * i + j] = 1
            rows += [e[None], -e[None]]
            rhs += [[lo], [-hi]]
    return G, a, rows, rhs


def _solve_qp(points, idx, G, a, rows, rhs):
    f = quadprog.solve_qp(G, a, np.vstack(rows).T, np.concatenate([np.ravel(x) for x in rhs]), 3)[0]
    full = np.zeros((len(points), 3))
    full[idx] = f.reshape(-1, 3)
    return full


def reference_forces(points, contact, com, f_lin, f_ang, mu=0.65):
    """Eq. 14 written directly for quadprog, in newtons, variables for contact points only."""
    idx = np.flatnonzero(contact)
    return _solve_qp(points, idx, *eq14_for_quadprog(points, idx, com, f_lin, f_ang, mu))


def force_objective(forces, points, com, f_ang):
    def skew(r):
        return np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])

    W = np.hstack([skew(r) for r in points - com])
    f = forces.reshape(-1)
    return (
        np.sum(forces[:, :2] ** 2)
        + 0.5 * np.sum(forces[:, 2] ** 2)
        + 5000 * np.sum((f_ang - W @ f) ** 2)
    )


@pytest.fixture(scope="module")
def contact_batch():
    rng = np.random.default_rng(1)
    problems = [contact_problem(rng) for _ in range(1000)]
    refs = [reference_forces(*p) for p in problems]
    solver = jax.jit(jax.vmap(lambda *a: solve_contact_forces(*a)))
    batch = [jnp.asarray(np.stack(z)) for z in zip(*problems, strict=True)]
    return problems, refs, solver(*batch)


def relative_errors(problems, refs, solution):
    errs = []
    for i, (points, _c, com, _fl, f_ang) in enumerate(problems):
        o_ref = force_objective(refs[i], points, com, f_ang)
        o = force_objective(np.asarray(solution.forces[i]), points, com, f_ang)
        errs.append(abs(o - o_ref) / max(abs(o_ref), 1e-9))
    return np.array(errs)


def test_force_qp_typical_accuracy_against_quadprog(contact_batch):
    problems, refs, sol = contact_batch
    errs = relative_errors(problems, refs, sol)
    assert np.median(errs) < 1e-8
    # Whatever the accuracy, the linear CoM force is met and every number is finite.
    assert float(jnp.max(sol.linear_residual)) < 1e-2
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(sol))
    # Points out of contact carry no force.
    for i, (_p, contact, *_rest) in enumerate(problems):
        assert np.all(np.asarray(sol.forces[i])[~contact] == 0.0)


def test_force_qp_meets_the_target_on_every_problem(contact_batch):
    """>= 1000 random feasible single/double support problems at the default iterations:
    objective within 1e-3 relative of quadprog, the cone and bounds met."""
    problems, refs, sol = contact_batch
    errs = relative_errors(problems, refs, sol)
    assert len(problems) >= 1000
    assert np.max(errs) < 1e-3, np.sort(errs)[-5:]
    assert cone_violation(np.asarray(sol.forces), 0.65) < 1e-9
    assert not bool(jnp.any(sol.relaxed))  # all feasible at mu = 0.65: never relaxed


def cone_violation(forces, mu, fz_min=5.0, fz_max=3000.0, ft_max=1000.0):
    """Largest violation (N) of the pyramid and bounds by forces of points in contact
    (rows with any force; the rest must be exactly zero)."""
    f = forces.reshape(-1, 3)
    on = np.any(f != 0.0, axis=1)
    f = f[on]
    return max(
        0.0,
        float(np.max(np.abs(f[:, :2]) - mu * f[:, 2:3], initial=0.0)),
        float(np.max(np.abs(f[:, :2]) - ft_max, initial=0.0)),
        float(np.max(fz_min - f[:, 2], initial=0.0)),
        float(np.max(f[:, 2] - fz_max, initial=0.0)),
    )


def quadprog_projection(v, lo, hi, mu, ft_max):
    """Euclidean projection of v onto the pyramid and bounds, by quadprog."""
    rows, rhs = [], []
    for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        rows.append([-sx, -sy, mu])
        rhs.append(0.0)
    for j, (a, b) in enumerate(((-ft_max, ft_max), (-ft_max, ft_max), (lo, hi))):
        e = np.zeros(3)
        e[j] = 1.0
        rows += [e, -e]
        rhs += [a, -b]
    return quadprog.solve_qp(np.eye(3), v, np.array(rows).T, np.array(rhs), 0)[0]


def test_point_projection_matches_quadprog():
    rng = np.random.default_rng(7)
    cases = rng.normal(0, 8, (2000, 3)) * rng.choice([0.1, 1.0, 10.0], (2000, 1))
    los = rng.uniform(0.0, 0.5, 2000)
    his = los + rng.choice([1e-3, 0.1, 5.0, 30.0], 2000)
    mus = rng.choice([0.65, 1.75], 2000)
    caps = rng.choice([2.0, 10.0, 1e9], 2000)
    got = np.stack(
        jax.jit(jax.vmap(project_point))(
            *(jnp.asarray(x) for x in (*cases.T, los, his, mus, caps))
        ),
        -1,
    )
    for i in range(len(cases)):
        ref = quadprog_projection(cases[i], los[i], his[i], mus[i], min(caps[i], 1e6))
        np.testing.assert_allclose(got[i], ref, atol=1e-8 * (1 + np.abs(cases[i]).max()))


def test_net_force_feasibility_matches_quadprog():
    """The closed-form test says feasible exactly when quadprog finds forces within the
    points' sets that sum to the net force (away from the boundary itself)."""
    rng = np.random.default_rng(8)
    prm = ForceQPParams()
    agree = 0
    for k in range(300):
        points, contact, _com, _f, _a = contact_problem(rng, max_accel=10.0)
        f_lin = 135.9 * np.r_[rng.uniform(-10, 10, 2), rng.uniform(-9.0, 15.0) + 9.81]
        fz_max = rng.choice([3000.0, 900.0, 40.0], len(points))
        mu = [0.65, 1.75][k % 2]
        got = bool(
            net_force_feasible(
                jnp.asarray(f_lin), jnp.asarray(contact), jnp.asarray(fz_max), mu, prm
            )
        )
        m = int(contact.sum())
        rows, rhs = [np.tile(np.eye(3), (1, m))], [f_lin]
        for i, hi in enumerate(fz_max[contact]):
            for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                r = np.zeros(3 * m)
                r[3 * i : 3 * i + 3] = [-sx, -sy, mu]
                rows.append(r[None])
                rhs.append([0.0])
            for j, (lo, up) in enumerate(((-1000, 1000), (-1000, 1000), (5.0, hi))):
                e = np.zeros(3 * m)
                e[3 * i + j] = 1
                rows += [e[None], -e[None]]
                rhs += [[lo], [-up]]
        try:
            quadprog.solve_qp(
                np.eye(3 * m),
                np.zeros(3 * m),
                np.vstack(rows).T,
                np.concatenate([np.ravel(x) for x in rhs]),
                3,
            )
            expected = True
        except ValueError:
            expected = False
        assert got == expected, (k, f_lin, fz_max, mu)
        agree += 1
    assert agree == 300


def test_infeasible_cone_is_relaxed_and_flagged():
    rng = np.random.default_rng(3)
    points, contact, com, _f, f_ang = contact_problem(rng)
    f_lin = 135.9 * np.array([8.0, 0.0, 9.81])  # needs mu > 0.8 > 0.65
    sol = solve_contact_forces(
        jnp.asarray(points),
        jnp.asarray(contact),
        jnp.asarray(com),
        jnp.asarray(f_lin),
        jnp.asarray(f_ang),
    )
    assert bool(sol.relaxed) and not bool(sol.infeasible)
    forces = np.asarray(sol.forces)[contact]
    assert cone_violation(forces, 1.75) < 1e-9
    assert np.max(np.abs(forces[:, :2]) - 0.65 * forces[:, 2:3]) > 1.0  # beyond mu
    assert float(sol.linear_residual) < 1e-2


def test_impossible_net_force_is_flagged_with_finite_forces():
    """Pulling the robot off the floor, more friction than 1.75, no point in contact, or
    NaN: flags and finite numbers, never NaN."""
    rng = np.random.default_rng(4)
    points, contact, com, f_lin, f_ang = contact_problem(rng)
    cases = [
        (contact, np.array([0.0, 0.0, -100.0])),
        (contact, 135.9 * np.array([25.0, 0.0, 9.81])),
        (np.zeros(8, bool), f_lin),
        (contact, np.array([np.nan, 0.0, 1333.0])),
    ]
    for c, fl in cases:
        sol = solve_contact_forces(
            jnp.asarray(points),
            jnp.asarray(c),
            jnp.asarray(com),
            jnp.asarray(fl),
            jnp.asarray(f_ang),
        )
        assert bool(sol.infeasible) and bool(sol.relaxed)
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(sol)), fl
        forces = np.asarray(sol.forces)
        assert np.all(forces[~np.asarray(c)] == 0.0)
        assert cone_violation(forces, 1.75) < 1e-9


def test_params_validation():
    with pytest.raises(ValueError, match=r"ForceQPParams\.mu must be in \(0, mu_relaxed"):
        ForceQPParams(mu=2.0)
    with pytest.raises(ValueError, match="alpha"):
        ForceQPParams(alpha=2.0)
    with pytest.raises(ValueError, match="rho"):
        ForceQPParams(rho=0.0)
    with pytest.raises(ValueError, match="iterations"):
        ForceQPParams(iterations=0)


def closed_loop_sequence(rng, ticks: int = 600):
    """A 1 kHz sequence of problems on one contact set (both feet, 8 points): a CoM force
    swinging sideways, weight shifting to one foot over 0.6 s. Returns ``(points,
    in_contact, com)`` and ``[f_lin, f_ang, fz_max]`` stacked over the ticks."""
    points, _contact, com, _f, _a = contact_problem(rng)
    t = np.linspace(0.0, 1.0, ticks)
    f_lin = 135.9 * np.stack([2.0 * np.sin(2 * np.pi * t), 1.5 * t, 9.81 + 0.5 * np.cos(3 * t)], -1)
    f_ang = np.stack([10 * np.sin(4 * t), 5 * t, np.zeros_like(t)], -1)
    fz_max = np.stack(
        [np.r_[np.full(4, 3000.0), np.full(4, 3000.0 * (1 - s) + 5.0 * s)] for s in t]
    )
    args = (jnp.asarray(points), jnp.asarray(np.ones(8, bool)), jnp.asarray(com))
    return args, [jnp.asarray(a) for a in (f_lin, f_ang, fz_max)]


def test_warm_started_closed_loop_settings_track_the_cold_solution():
    """The walking preset's fewer iterations rely on each tick starting from the last
    tick's solution: along a sequence of problems at 1 kHz (a CoM force swinging sideways,
    weight shifting to one foot over 0.6 s) they give the cold solution's forces, except
    for a few ticks after the set of active constraints changes (measured with the preset,
    150 iterations at rho 0.02: median 1.2e-4 N, largest 2.3 N)."""
    from jaxloco.control.presets import CLOSED_LOOP_QP, walking_config

    assert walking_config().force_qp == CLOSED_LOOP_QP
    assert CLOSED_LOOP_QP.iterations < ForceQPParams().iterations
    args, seq = closed_loop_sequence(np.random.default_rng(4))
    cold_params = ForceQPParams(iterations=2000)
    cold = jax.vmap(lambda fl, fa, fz: solve_contact_forces(*args, fl, fa, cold_params, fz_max=fz))(
        *seq
    )

    def tick(warm, inputs):
        fl, fa, fz = inputs
        sol = solve_contact_forces(*args, fl, fa, CLOSED_LOOP_QP, fz_max=fz, warm_start=warm)
        return sol.warm_start, sol

    _, warm = jax.jit(lambda s: jax.lax.scan(tick, zero_warm_start(8), s))(seq)
    assert not bool(jnp.any(cold.relaxed)) and not bool(jnp.any(warm.relaxed))
    error = np.abs(np.asarray(warm.forces) - np.asarray(cold.forces)).max(axis=(1, 2))[5:]
    assert np.median(error) < 1e-3, np.median(error)
    assert np.mean(error < 0.1) > 0.9, np.mean(error < 0.1)
    assert error.max() < 5.0, error.max()


def test_warm_started_torque_row_settings_track_the_cold_solution():
    """The walking preset with torque rows (``CLOSED_LOOP_TORQUE_QP``, half the iterations
    of ``CLOSED_LOOP_QP``) along a 1 kHz sequence whose leg-like torque limits bind on most
    ticks: the forces stay near the converged solve's and every torque within its limit to
    a fraction of a newton metre (measured: median 0.39 N, largest 47 N, excess at most
    0.22 N m; ``CLOSED_LOOP_QP`` with the same rows: 0.12 N, 11 N, 0.33 N m)."""
    from jaxloco.control.force_qp import TorqueRows
    from jaxloco.control.presets import CLOSED_LOOP_TORQUE_QP

    rng = np.random.default_rng(4)
    args, seq = closed_loop_sequence(rng)
    n, m = 8, 12
    g = np.zeros((m, 3 * n))
    for foot in range(2):
        for i in range(4 * foot, 4 * foot + 4):
            for c in range(3):
                g[6 * foot : 6 * foot + 6, c * n + i] = rng.normal(0, 0.3, 6)
    offset = rng.normal(0, 30, m)

    def cold(params, rows=None):
        return jax.vmap(
            lambda fl, fa, fz: solve_contact_forces(*args, fl, fa, params, fz_max=fz, torques=rows)
        )(*seq)

    free = np.asarray(cold(ForceQPParams(iterations=1000)).forces)
    torques = offset - free.transpose(0, 2, 1).reshape(len(free), -1) @ g.T
    limit = np.maximum(0.8 * np.abs(torques).max(axis=0), 5.0)  # each binds somewhere
    rows = TorqueRows(jnp.asarray(g), jnp.asarray(offset), jnp.asarray(limit))
    converged = cold(ForceQPParams(iterations=3000), rows)
    bound = np.abs(offset - np.asarray(converged.forces).transpose(0, 2, 1).reshape(600, -1) @ g.T)
    assert np.mean(np.any(bound > limit - 1e-3, axis=1)) > 0.5  # limits bind on most ticks

    def tick(warm, inputs):
        fl, fa, fz = inputs
        sol = solve_contact_forces(
            *args, fl, fa, CLOSED_LOOP_TORQUE_QP, fz_max=fz, warm_start=warm, torques=rows
        )
        return sol.warm_start, sol

    start = zero_warm_start(8, jnp.float64, m)
    _, warm = jax.jit(lambda s: jax.lax.scan(tick, start, s))(seq)
    error = np.abs(np.asarray(warm.forces) - np.asarray(converged.forces)).max(axis=(1, 2))[5:]
    assert np.median(error) < 1.0, np.median(error)
    assert error.max() < 100.0, error.max()
    assert float(jnp.max(warm.torque_excess)) < 1.0


def test_float32_forces_do_not_depend_on_how_the_solve_is_batched():
    """Regression: float32 forces must not depend on batching or compilation. Solved
    alone, in a vmapped batch, and in a batch with another problem per row, the relaxation
    flags are identical (they are decided in closed form) and the forces agree to float32
    round-off of the iterations."""
    rng = np.random.default_rng(3)
    problems = [contact_problem(rng, max_accel=6.0) for _ in range(64)]
    batch = [
        jnp.asarray(np.stack(z), None if k == 1 else jnp.float32)
        for k, z in enumerate(zip(*problems, strict=True))
    ]
    prm = ForceQPParams(iterations=200)

    def solve(*a):
        return solve_contact_forces(*a, params=prm)

    batched = jax.jit(jax.vmap(solve))(*batch)
    paired = jax.jit(jax.vmap(lambda *a: jax.vmap(solve)(*(jnp.stack([x, x[::-1]]) for x in a))))(
        *batch
    )
    paired = jax.tree.map(lambda x: x[:, 0], paired)
    alone = jax.jit(solve)
    relaxed = np.asarray(batched.relaxed)
    assert 0 < relaxed.sum() < len(problems)  # both kinds present
    np.testing.assert_array_equal(np.asarray(paired.relaxed), relaxed)
    np.testing.assert_allclose(np.asarray(paired.forces), np.asarray(batched.forces), atol=0.05)
    for i in range(0, 64, 8):
        one = alone(*(x[i] for x in batch))
        assert bool(one.relaxed) == bool(relaxed[i])
        np.testing.assert_allclose(np.asarray(one.forces), np.asarray(batched.forces[i]), atol=0.05)


def test_force_gradients_match_finite_differences():
    """Forces are differentiable in the commands (through the unrolled iterations)."""
    points, contact, com, f_lin, f_ang = contact_problem(np.random.default_rng(9))
    prm = ForceQPParams(iterations=300)

    def forces(fl, fa):
        sol = solve_contact_forces(jnp.asarray(points), jnp.asarray(contact), com, fl, fa, prm)
        return sol.forces

    check_grads(
        forces,
        (jnp.asarray(f_lin), jnp.asarray(f_ang)),
        order=1,
        modes=("fwd", "rev"),
        eps=1e-3,
        atol=1e-4,
        rtol=1e-4,
    )


def test_iterations_change_accuracy_not_shapes(contact_batch):
    """Fewer iterations give a less accurate but still feasible answer (the cone is met by
    construction); more converge (median relative objective error falls)."""
    problems, refs, _ = contact_batch
    batch = [jnp.asarray(np.stack(z)) for z in zip(*problems[:200], strict=True)]
    medians = []
    for it in (25, 100):
        prm = dataclasses.replace(ForceQPParams(), iterations=it)
        sol = jax.jit(jax.vmap(lambda *a, p=prm: solve_contact_forces(*a, params=p)))(*batch)
        assert cone_violation(np.asarray(sol.forces), 0.65) < 1e-9
        medians.append(np.median(relative_errors(problems[:200], refs[:200], sol)))
    assert medians[1] < 0.1 * medians[0]


def _torque_problem(rng, tight):
    """A contact problem with 12 leg-like torque rows (6 per foot, each a map of that
    foot's forces) whose limits are ``tight`` times the unconstrained solution's torques."""
    from jaxloco.control.force_qp import TorqueRows

    points, contact, com, f_lin, f_ang = contact_problem(rng)
    n, m = len(points), 12
    g = np.zeros((m, 3 * n))
    for foot in range(2):
        for i in range(4 * foot, 4 * foot + 4):
            for c in range(3):
                g[6 * foot : 6 * foot + 6, c * n + i] = rng.normal(0, 0.3, 6)
    free = np.asarray(solve_contact_forces(points, contact, com, f_lin, f_ang).forces)
    offset = rng.normal(0, 30, m)
    tau = offset - g @ free.T.reshape(-1)
    limit = np.maximum(np.abs(tau) * tight * rng.uniform(0.7, 1.5, m), 5.0)
    return (points, contact, com, f_lin, f_ang), TorqueRows(g, offset, limit)


def reference_forces_with_torques(points, contact, com, f_lin, f_ang, rows):
    """Eq. 14 plus ``|offset - G f| <= limit`` for quadprog (None when infeasible)."""
    n, idx = len(points), np.flatnonzero(contact)
    gk = np.stack([rows.matrix[:, c * n + i] for i in idx for c in range(3)], axis=1)
    G, a, cons, rhs = eq14_for_quadprog(points, idx, com, f_lin, f_ang)
    cons += [gk, -gk]
    rhs += [rows.offset - rows.limit, -rows.offset - rows.limit]
    try:
        return _solve_qp(points, idx, G, a, cons, rhs)
    except ValueError:
        return None


def test_torque_limit_rows_against_quadprog():
    """With torque rows (float64, cold, 1000 iterations), on problems where some limits
    bind and quadprog finds a solution: the objective matches quadprog's and the torques
    keep their limits, for most problems to 1e-4; ADMM converges slowly on a few, whose
    excess is still reported. Loose limits change nothing."""
    rng = np.random.default_rng(0)
    params = ForceQPParams(iterations=1000)
    problems, refs = [], []
    while len(problems) < 40:
        problem, rows = _torque_problem(rng, tight=1.0)
        ref = reference_forces_with_torques(*problem, rows)
        if ref is not None:
            problems.append((problem, rows))
            refs.append(ref)
    batch = [jnp.asarray(np.stack(z)) for z in zip(*(p for p, _ in problems), strict=True)]
    rows = jax.tree.map(lambda *xs: jnp.asarray(np.stack(xs)), *(r for _, r in problems))
    solve = jax.jit(jax.vmap(lambda *a: solve_contact_forces(*a[:5], params, torques=a[5])))
    sol = solve(*batch, rows)
    errors, excess = [], []
    for i, ((problem, row), ref) in enumerate(zip(problems, refs, strict=True)):
        points, _c, com, _fl, f_ang = problem
        forces = np.asarray(sol.forces[i])
        o_ref = force_objective(ref, points, com, f_ang)
        errors.append(abs(force_objective(forces, points, com, f_ang) - o_ref) / o_ref)
        tau = row.offset - row.matrix @ forces.T.reshape(-1)
        excess.append(max(np.max(np.abs(tau) - row.limit), 0.0))
        np.testing.assert_allclose(float(sol.torque_excess[i]), excess[-1], atol=1e-6)
        assert float(sol.linear_residual[i]) < 1.0  # N, of a net force over 1000 N
    errors, excess = np.array(errors), np.array(excess)
    assert np.median(errors) < 1e-4 and np.mean(errors < 1e-2) >= 0.8, errors
    assert np.median(excess) < 1e-3 and np.mean(excess < 0.5) >= 0.8, excess
    # Limits far from binding: the plain QP's forces.
    problem, loose = _torque_problem(rng, tight=100.0)
    plain = solve_contact_forces(*problem, params)
    with_rows = solve_contact_forces(*problem, params, torques=loose)
    np.testing.assert_allclose(with_rows.forces, plain.forces, atol=1e-3)
    assert float(with_rows.torque_excess) == 0.0


def test_unreachable_torque_limits_are_reported_not_forced():
    """Limits no forces can meet: the net force is still carried (the duals are bounded),
    the forces stay finite and the excess is reported."""
    from jaxloco.control.force_qp import TorqueRows

    rng = np.random.default_rng(3)
    problem, rows = _torque_problem(rng, tight=1.0)
    impossible = TorqueRows(rows.matrix, rows.offset + 1e4, rows.limit)
    warm = zero_warm_start(8, jnp.float64, 12)
    for _ in range(20):  # a closed loop would carry the duals tick after tick
        sol = solve_contact_forces(
            *problem, ForceQPParams(iterations=150), warm_start=warm, torques=impossible
        )
        warm = sol.warm_start
    assert np.all(np.isfinite(sol.forces))
    assert float(sol.linear_residual) < 1.0
    assert float(sol.torque_excess) > 1e3
    with pytest.raises(ValueError, match="warm_start has 0 torque rows, the problem 12"):
        solve_contact_forces(*problem, warm_start=zero_warm_start(8), torques=impossible)
