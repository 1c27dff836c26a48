"""Measurement models: analytic Jacobians vs central differences, closed-form initial
guesses, simulation, and the StackedProblem contract."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.measure.base import (
    ParamSpec,
    frame_rotation_axes,
    lstsq,
    stack,
    svd_thin,
)
from kincal.measure.instruments.common import inverse_left_jacobian_so3, kabsch
from kincal.measure.instruments.pose import PoseMeasurement, simulate_poses
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import load_serial_robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import (
    exp_so3,
    frame_from_matrix,
    log_so3,
    matrix_from_frame,
    xyzrpy_to_matrix,
)

INSTRUMENT = [1.4, -0.6, 0.3, 2.1, -0.3, 0.2]          # x y z rz ry rx


def puma():
    return load_serial_robot("puma560")


def stanford():
    """Stanford arm (RRPRRR) in standard DH, with a prismatic third joint."""
    return load_serial_robot("stanford").with_params({"tool.x": 0.02, "tool.y": -0.01,
                                                      "tool.z": 0.08})


def central_differences(prob, theta, h=1e-6):
    J = np.zeros((prob.residuals(theta).size, theta.size))
    for k in range(theta.size):
        e = np.zeros(theta.size)
        e[k] = h
        J[:, k] = (prob.residuals(theta + e) - prob.residuals(theta - e)) / (2 * h)
    return J


def blocks(robot, rng):
    q = random_configurations(robot, 12, rng)
    true = perturb_robot(robot, rng)
    return [
        simulate_positions(true, q, rng, 1e-5, INSTRUMENT, [0.02, -0.03, 0.07]),
        simulate_positions(true, q, rng, 1e-5, INSTRUMENT,
                           [[0.02, -0.03, 0.07], [-0.05, 0.01, 0.1], [0.0, 0.06, 0.02]],
                           name="mocap"),
        simulate_poses(true, q, rng, 1e-5, 2e-5, INSTRUMENT, [0.01, 0.02, 0.1, 0.4, -0.2, 0.3],
                       name="laser"),
    ]


@pytest.mark.parametrize("robot_fn", [puma, stanford])
@pytest.mark.parametrize("which", [0, 1, 2])
def test_jacobian_matches_central_differences(robot_fn, which):
    rng = np.random.default_rng(10 + which)
    robot = robot_fn()
    blk = blocks(robot, rng)[which]
    prob, theta = stack(robot, [blk])
    theta = theta + 1e-3 * rng.standard_normal(theta.size)   # away from the data
    r, J = prob.residuals_and_jacobian(theta)
    Jn = central_differences(prob, theta)
    # truncation error of central differences ~ h^2 * third derivative; residuals are
    # O(1/sigma) = O(1e5) per metre, so compare relative to the column scale
    scale = np.maximum(np.abs(J).max(axis=0), 1.0)
    err = np.abs(J - Jn).max(axis=0) / scale
    worst = int(np.argmax(err))
    assert err.max() < 1e-6, f"column {prob.names[worst]} differs by {err.max():.2e}"
    assert np.allclose(r, prob.residuals(theta))


def test_inverse_left_jacobian():
    rng = np.random.default_rng(0)
    for angle in (1e-7, 1e-3, 0.5, 2.5):
        phi = rng.standard_normal(3)
        phi *= angle / np.linalg.norm(phi)
        Jl = inverse_left_jacobian_so3(phi)
        h = 1e-6
        num = np.column_stack([(log_so3(exp_so3(h * e) @ exp_so3(phi))
                                - log_so3(exp_so3(-h * e) @ exp_so3(phi))) / (2 * h)
                               for e in np.eye(3)])
        assert np.allclose(Jl, num, atol=1e-8)


def test_frame_helpers():
    v = np.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])
    T = matrix_from_frame(v)
    assert np.allclose(T, xyzrpy_to_matrix([0.1, -0.2, 0.3, 0.6, -0.5, 0.4]))
    assert np.allclose(frame_from_matrix(T), v)
    E = frame_rotation_axes(v)
    h = 1e-6
    for c, k in enumerate((3, 4, 5)):
        e = np.zeros(6)
        e[k] = h
        dR = (matrix_from_frame(v + e)[:3, :3] - matrix_from_frame(v - e)[:3, :3]) / (2 * h)
        W = dR @ T[:3, :3].T
        assert np.allclose([W[2, 1], W[0, 2], W[1, 0]], E[:, c], atol=1e-8)


def test_linear_algebra_helpers():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((40, 6))
    U, S, Vt = svd_thin(A)
    assert np.allclose(U * S @ Vt, A)
    assert np.allclose(S, np.linalg.svd(A, compute_uv=False))
    b = rng.standard_normal(40)
    assert np.allclose(lstsq(A, b), np.linalg.lstsq(A, b, rcond=None)[0])
    R, t = kabsch(A[:, :3], A[:, :3] @ exp_so3([0.3, -0.2, 0.1]).T + [1, 2, 3])
    assert np.allclose(R, exp_so3([0.3, -0.2, 0.1])) and np.allclose(t, [1, 2, 3])


@pytest.mark.parametrize("which", [0, 1, 2])
def test_initial_guess_is_exact_for_exact_data(which):
    """With the true robot and noise-free data the closed form recovers the truth."""
    rng = np.random.default_rng(3)
    robot = puma()
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, 15, rng)
    blk = [simulate_positions(true, q, rng, 0.0, INSTRUMENT, [0.02, -0.03, 0.07]),
           simulate_positions(true, q, rng, 0.0, INSTRUMENT, [[0.02, -0.03, 0.07],
                                                             [-0.05, 0.01, 0.1]]),
           simulate_poses(true, q, rng, 0.0, 0.0, INSTRUMENT,
                          [0.01, 0.02, 0.1, 0.4, -0.2, 0.3])][which]
    guess = blk.initial_guess(true)
    assert np.allclose(guess[:6], np.asarray(INSTRUMENT), atol=1e-9)
    r, _, _ = blk.evaluate(true, guess, jacobian=False)
    assert np.abs(r).max() * 1e-5 < 1e-10          # metres


def test_initial_guess_of_many_configurations_uses_an_evenly_spaced_subset(monkeypatch):
    """Beyond GUESS_CONFIGURATIONS the closed form sees only evenly spaced ones: with
    exact data it is still exact (every configuration is consistent), with noise it
    is a start within a few noise standard deviations of the all-data one, and the
    calibration from it ends at the same estimate (within the solver's 1e-3 standard
    errors)."""
    from kincal.identify.solver import calibrate
    from kincal.measure.instruments import position

    rng = np.random.default_rng(8)
    robot = puma()
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, 3000, rng)
    marker = [0.02, -0.03, 0.07]
    exact = simulate_positions(true, q, rng, 0.0, INSTRUMENT, marker)
    seen = []
    fk = type(true).fk

    def counting(self, qs):
        seen.append(len(qs))
        return fk(self, qs)

    monkeypatch.setattr(type(true), "fk", counting)
    guess = exact.initial_guess(true)
    monkeypatch.undo()
    assert sum(seen) == position.GUESS_CONFIGURATIONS
    assert np.allclose(guess[:6], np.asarray(INSTRUMENT), atol=1e-9)
    assert np.allclose(guess[6:], marker, atol=1e-9)
    noisy = simulate_positions(true, q, rng, 1e-5, INSTRUMENT, marker)
    sub = noisy.initial_guess(robot)
    res = calibrate(robot, [noisy])
    monkeypatch.setattr(position, "GUESS_CONFIGURATIONS", 10**9)
    full = noisy.initial_guess(robot)
    ref = calibrate(robot, [noisy])
    # both starts carry the nominal model's error (here the frame 8 mm off); the subset
    # moves it by a small fraction of that (0.14 mm)
    truth = np.asarray(INSTRUMENT)[:3]
    assert np.linalg.norm(sub[:3] - full[:3]) < 0.1 * np.linalg.norm(full[:3] - truth)
    # each fit ends within 1e-3 standard errors of the same minimum (tol_std)
    est = [res.names.index(n) for n in res.estimated]
    assert res.estimated == ref.estimated
    assert np.max(np.abs(res.theta[est] - ref.theta[est]) / res.std[est]) < 2e-3


def test_position_block_contract():
    rng = np.random.default_rng(4)
    robot = puma()
    q = random_configurations(robot, 7, rng)
    blk = simulate_positions(robot, q, rng, 2e-5, INSTRUMENT, [[0, 0, 0.1], [0, 0.1, 0]])
    spec = blk.parameters()
    assert spec.names[:6] == tuple(f"tracker.{f}" for f in ("x", "y", "z", "rz", "ry", "rx"))
    assert spec.names[6:] == ("tracker.marker1.x", "tracker.marker1.y", "tracker.marker1.z",
                              "tracker.marker2.x", "tracker.marker2.y", "tracker.marker2.z")
    assert blk.residual_owner().tolist() == np.repeat(np.arange(7), 6).tolist()
    e = blk.errors(robot, blk.initial_guess(robot))["position_m"]
    assert e.shape == (7, 2)
    sub = blk.subset([0, 3])
    assert sub.q.shape == (2, 6) and sub.name == "tracker"
    one = simulate_positions(robot, q, rng, 1e-5)
    assert one.parameters().names[-3:] == ("tracker.marker.x", "tracker.marker.y",
                                           "tracker.marker.z")
    assert one.errors(robot, one.initial_guess(robot))["position_m"].shape == (7,)


def test_pose_errors_and_whitening():
    rng = np.random.default_rng(5)
    robot = puma()
    q = random_configurations(robot, 9, rng)
    blk = simulate_poses(robot, q, rng, 0.0, 0.0, INSTRUMENT)
    extra = blk.initial_guess(robot)
    extra[0] += 1e-3                                   # shift the instrument 1 mm along x
    errs = blk.errors(robot, extra)
    assert np.allclose(errs["position_m"], 1e-3) and np.allclose(errs["orientation_rad"], 0)
    r, _, _ = blk.evaluate(robot, extra, jacobian=False)
    assert np.allclose(np.linalg.norm(r.reshape(9, 6)[:, :3], axis=1), 1e-3 / 1e-5)


def test_bad_inputs_are_one_line_errors():
    q = np.zeros((3, 6))
    with pytest.raises(KincalError, match="positions"):
        PositionMeasurement(q, np.zeros((4, 3)))
    with pytest.raises(KincalError, match="sigma"):
        PositionMeasurement(q, np.zeros((3, 3)), sigma=-1.0)
    with pytest.raises(KincalError, match="not finite"):
        PositionMeasurement(q, np.full((3, 3), np.nan))
    with pytest.raises(KincalError, match="poses"):
        PoseMeasurement(q, np.zeros((3, 3, 3)))
    with pytest.raises(KincalError, match="6 joints"):
        stack(load_serial_robot("puma560"),
              [PositionMeasurement(np.zeros((3, 5)), np.zeros((3, 3)))])
    b = PositionMeasurement(q, np.zeros((3, 3)))
    with pytest.raises(KincalError, match="both named"):
        stack(load_serial_robot("puma560"), [b, b])


def test_random_configurations_and_perturbation():
    rng = np.random.default_rng(6)
    robot = stanford()
    q = random_configurations(robot, 500, rng, margin=0.1)
    lim = robot.joint_limits
    span = lim[:, 1] - lim[:, 0]
    assert np.all(q >= lim[:, 0] + 0.1 * span - 1e-12) and np.all(q <= lim[:, 1] - 0.1 * span)
    free = from_dh([DHLink(a=0.3), DHLink(a=0.2)])                      # unlimited revolute
    assert np.all(np.abs(random_configurations(free, 50, rng)) <= np.pi)
    with pytest.raises(KincalError, match="q2"):
        random_configurations(from_dh([DHLink(a=0.3), DHLink(joint="prismatic")]), 5, rng)
    true = perturb_robot(robot, rng, names=["d[1]", "theta_offset[2]"])
    diff = true.param_values - robot.param_values
    changed = [n for n, d in zip(robot.param_names, diff, strict=True) if d != 0]
    assert changed == ["theta_offset[2]", "d[1]"] or set(changed) == {"d[1]", "theta_offset[2]"}
    # standard deviations by role over many draws
    many = np.array([perturb_robot(robot, np.random.default_rng(s)).param_values
                     for s in range(300)]) - robot.param_values
    std = many.std(axis=0)
    i = robot.param_index
    assert std[i("a[2]")] == pytest.approx(1e-3, rel=0.15)
    assert std[i("theta_offset[1]")] == pytest.approx(np.deg2rad(0.1), rel=0.15)
    assert std[i("d[3]")] == pytest.approx(1e-3, rel=0.15)            # prismatic offset (m)
    assert std[i("alpha[4]")] == pytest.approx(np.deg2rad(0.05), rel=0.15)


def test_paramspec_helpers():
    s = ParamSpec.frame("cam") + ParamSpec.point("cam.tip")
    assert len(s) == 9 and s.units[:3] == ("m",) * 3 and s.roles[-1] == "tool_point"


# --------------------------------------------------------------------------- large problems
def _problem(n, seed=11):
    """PUMA 560, n configurations, three blocks (1 marker, 3 markers, poses)."""
    rng = np.random.default_rng(seed)
    robot = puma()
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, n, rng)
    blks = [
        simulate_positions(true, q, rng, 1e-5, INSTRUMENT, [0.02, -0.03, 0.07]),
        simulate_positions(true, q[: n // 2], rng, 1e-5, INSTRUMENT,
                           [[0.02, -0.03, 0.07], [-0.05, 0.01, 0.1], [0.0, 0.06, 0.02]],
                           name="mocap"),
        simulate_poses(true, q, rng, 1e-5, 2e-5, INSTRUMENT, [0.01, 0.02, 0.1, 0.4, -0.2, 0.3],
                       name="laser"),
    ]
    prob, theta = stack(robot, blks)
    return prob, theta + 1e-4 * rng.standard_normal(theta.size), rng


@pytest.mark.parametrize("which", [0, 1, 2])
def test_chunks_are_pieces_of_evaluate(which):
    """evaluate_chunks covers the rows in order with evaluate's values (several pieces)."""
    prob, theta, _ = _problem(3000)
    robot, extras = prob.split(theta)
    blk, extra = prob.blocks[which], extras[which]
    r, Jr, Je = blk.evaluate(robot, extra)
    assert r.size == blk.num_residuals() == len(blk.residual_owner())
    assert np.allclose(r, blk.evaluate(robot, extra, jacobian=False)[0], rtol=0, atol=1e-9)
    stop = 0
    pieces = list(blk.evaluate_chunks(robot, extra, rows=500))
    assert len(pieces) > 3
    for sl, rc, Jrc, Jec in pieces:
        assert sl.start == stop and sl.stop - sl.start == rc.size <= 500
        assert np.array_equal(rc, r[sl]) and np.array_equal(Jrc, Jr[sl])
        assert np.array_equal(Jec, Je[sl])
        stop = sl.stop
    assert stop == r.size


def test_compressed_triangle_matches_the_full_jacobian():
    """R^T R = J^T W J, R^T z = J^T W r, ||z||^2 + rho^2 = r^T W r, on a column subset."""
    prob, theta, rng = _problem(2500)
    r, J = prob.residuals_and_jacobian(theta)
    w = rng.uniform(0.2, 1.0, r.size)
    cols = [int(c) for c in rng.permutation(len(prob.names))[:30]]
    c = prob.compressed(theta, w, cols, rows=700)
    Jw = J[:, cols] * np.sqrt(w)[:, None]
    rw = r * np.sqrt(w)
    N = Jw.T @ Jw
    assert np.allclose(c.R, np.triu(c.R)) and c.R.shape == (30, 30)
    assert np.allclose(c.R.T @ c.R, N, rtol=0, atol=1e-10 * np.abs(N).max())
    g = Jw.T @ rw
    assert np.allclose(c.R.T @ c.z, g, rtol=0, atol=1e-10 * np.abs(g).max())
    assert c.z @ c.z + c.rho**2 == pytest.approx(rw @ rw, rel=1e-10)
    assert c.cost == pytest.approx(0.5 * rw @ rw, rel=1e-12)
    # the same residuals, computed by another path (the point Jacobian of the chain run
    # from the instrument frame): equal to the rounding of metre-sized coordinates / sigma
    assert np.allclose(c.r, r, rtol=0, atol=1e-14 / 1e-5 * 100) and list(c.columns) == cols
    # the Gauss-Newton step equals the minimum-norm least-squares step of the full system
    assert np.allclose(c.solve(), -np.linalg.lstsq(Jw, rw, rcond=None)[0], rtol=1e-8, atol=0)
    A, b, cost = prob.normal_equations(theta, w, cols)
    # the cost is summed piece by piece: other pieces (rows=700 above), other rounding
    assert np.allclose(A, N, rtol=0, atol=1e-10 * np.abs(N).max())
    assert cost == pytest.approx(c.cost, rel=1e-13)
    # a subset of columns, and extra rows, without re-evaluating
    sub = c.select([3, 0, 7])
    ref = prob.compressed(theta, w, [cols[3], cols[0], cols[7]])
    assert np.allclose(sub.R.T @ sub.R, ref.R.T @ ref.R, rtol=1e-12, atol=0)
    assert np.allclose(sub.R.T @ sub.z, ref.R.T @ ref.z, rtol=1e-10, atol=1e-12)
    assert sub.rho == pytest.approx(ref.rho, rel=1e-10)
    X, y = rng.standard_normal((4, 30)), rng.standard_normal(4)
    more = c.with_rows(X, y, [1.0, 2.0, 0.5, 1.0])
    sw = np.sqrt([1.0, 2.0, 0.5, 1.0])
    Jx, rx = np.vstack([Jw, X * sw[:, None]]), np.concatenate([rw, y * sw])
    assert np.allclose(more.R.T @ more.R, Jx.T @ Jx, rtol=0, atol=1e-10 * np.abs(N).max())
    assert np.allclose(more.R.T @ more.z, Jx.T @ rx, rtol=0, atol=1e-10 * np.abs(g).max())
    assert more.r.size == r.size + 4 and more.cost == pytest.approx(0.5 * rx @ rx, rel=1e-12)


def test_compressed_never_forms_the_jacobian():
    """Peak memory of compressed() is a small fraction of the (M, P) Jacobian."""
    import tracemalloc

    prob, theta, _ = _problem(8000)
    M, P = prob.num_residuals(), len(prob.names)
    prob.compressed(theta)                                   # warm-up (caches, plans)
    tracemalloc.start()
    try:
        c = prob.compressed(theta)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert c.R.shape == (P, P)
    assert peak < 0.25 * M * P * 8, f"peak {peak / 1e6:.1f} MB for a {M * P * 8 / 1e6:.1f} MB J"


def test_workspace_memory_is_reused_and_never_escapes():
    """A workspace hands the same memory back for the same name (grown when too small),
    keeps at most its byte budget, and two workspaces never share; what compressed() and
    the residuals return is not such memory: a second evaluation at another theta leaves
    the first one's results as they were."""
    ws = ChainWorkspace()
    a = ws.array("test.a", (4, 5))
    b = ws.array("test.a", (2, 3))
    assert np.shares_memory(a, b) and b.shape == (2, 3) and b.flags.c_contiguous
    grown = ws.array("test.a", (40, 50))
    assert not np.shares_memory(grown, a)                            # grown: new memory
    assert ws.nbytes == 40 * 50 * 8
    assert not np.shares_memory(ChainWorkspace().array("test.a", (4, 5)), grown)
    small = ChainWorkspace(max_bytes=100)
    big = small.array("test.b", (4, 5))                              # over budget: not kept
    assert small.nbytes == 0 and not np.shares_memory(small.array("test.b", (4, 5)), big)
    prob, theta, rng = _problem(300)
    c1, r1 = prob.compressed(theta), prob.residuals(theta)
    kept = (c1.R.copy(), c1.z.copy(), c1.r.copy(), r1.copy())
    prob.compressed(theta + rng.normal(0, 1e-3, theta.size))
    prob.residuals(theta + rng.normal(0, 1e-3, theta.size))
    for now, then in zip((c1.R, c1.z, c1.r, r1), kept, strict=True):
        np.testing.assert_array_equal(now, then)


def test_measurement_ids_match_the_unique_pairs():
    prob, _, _ = _problem(50)
    bi, rows = prob.owners()
    _, ref = np.unique(np.stack([bi, rows], 1), axis=0, return_inverse=True)
    assert np.array_equal(prob.measurement_ids(), ref.reshape(-1))

    class Shuffled:                                        # rows not in order
        def __init__(self, owner):
            self.owner = owner

        def residual_owner(self):
            return self.owner

    prob2 = type(prob)(prob.robot, [Shuffled(np.array([3, 3, 0, 7, 0])),
                                    Shuffled(np.array([1, 1]))], (), (), (), [])
    assert prob2.measurement_ids().tolist() == [1, 1, 0, 2, 0, 3, 3]


@pytest.mark.parametrize("M,p", [(9001, 12), (5000, 40), (300, 7), (4096, 1)])
def test_tiled_qr_svd_and_lstsq_on_tall_matrices(M, p):
    from kincal.measure.base import r_factor, singular_values

    rng = np.random.default_rng(M + p)
    A = rng.standard_normal((M, p)) * np.logspace(0, -4, p)
    if p > 3:
        A[:, 2] = 0.0                                       # a zero column stays zero
        A[:, 3] = A[:, 0] - 2 * A[:, 1]                     # and a dependent one
    R = r_factor(A)
    assert R.shape == (p, p) and np.allclose(R, np.triu(R))
    assert np.allclose(R.T @ R, A.T @ A, rtol=0, atol=1e-12 * M)
    if p > 3:
        assert np.all(R[:, 2] == 0.0)
    S_ref = np.linalg.svd(A, compute_uv=False)
    U, S, Vt = svd_thin(A)
    assert np.allclose(S, S_ref, rtol=0, atol=1e-12 * S_ref[0])
    assert np.allclose(singular_values(A), S_ref, rtol=0, atol=1e-12 * S_ref[0])
    assert np.allclose((U * S) @ Vt, A, rtol=0, atol=1e-12 * np.abs(A).max())
    keep = S > 1e-10 * S[0]
    assert np.allclose(U[:, keep].T @ U[:, keep], np.eye(keep.sum()), atol=1e-12)
    b = rng.standard_normal(M)
    x_ref = np.linalg.lstsq(A, b, rcond=1e-10)[0]
    assert np.allclose(lstsq(A, b), x_ref, rtol=0, atol=1e-9 * np.abs(x_ref).max())


def test_residual_free_triangle():
    """CompressedSystem.residual_free() has the Gram matrix of (I - u u^T) W^1/2 J."""
    prob, theta, rng = _problem(600)
    r, J = prob.residuals_and_jacobian(theta)
    w = rng.uniform(0.2, 1.0, r.size)
    cols = list(range(10, 40))
    c = prob.compressed(theta, w, cols)
    Jw, rw = J[:, cols] * np.sqrt(w)[:, None], r * np.sqrt(w)
    u = rw / np.linalg.norm(rw)
    Pj = Jw - np.outer(u, u @ Jw)
    F = c.residual_free()
    assert F.shape == (30, 30) and np.allclose(F, np.triu(F))
    G = Pj.T @ Pj
    assert np.allclose(F.T @ F, G, rtol=0, atol=1e-10 * np.abs(G).max())
