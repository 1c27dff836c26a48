"""Measurement models: analytic Jacobians vs central differences, closed-form initial
guesses, simulation, and the StackedProblem contract."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.measure.base import (
    ParamSpec,
    frame_matrix,
    frame_rotation_axes,
    frame_values,
    lstsq,
    stack,
    svd_thin,
)
from kincal.measure.models import (
    PoseMeasurement,
    PositionMeasurement,
    inverse_left_jacobian_so3,
    kabsch,
)
from kincal.measure.simulate import (
    instrument_values,
    perturb_robot,
    random_configurations,
    simulate_poses,
    simulate_positions,
)
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import load_robot
from kincal.spatial import exp_so3, log_so3, xyzrpy_to_matrix

INSTRUMENT = [1.4, -0.6, 0.3, 0.2, -0.3, 2.1]          # x y z roll pitch yaw


def puma():
    return load_robot("puma560")


def stanford():
    """Stanford arm (RRPRRR) in standard DH, with a prismatic third joint."""
    links = [DHLink(d=0.412, alpha=-np.pi / 2, lower=-2.8, upper=2.8),
             DHLink(d=0.154, alpha=np.pi / 2, lower=-2.8, upper=2.8),
             DHLink(theta_offset=-np.pi / 2, joint="prismatic", lower=0.3, upper=0.9),
             DHLink(alpha=-np.pi / 2, lower=-2.8, upper=2.8),
             DHLink(alpha=np.pi / 2, lower=-2.0, upper=2.0),
             DHLink(d=0.263, lower=-2.8, upper=2.8)]
    return from_dh(links, name="stanford", tool=[0.02, -0.01, 0.08, 0, 0, 0])


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
        simulate_poses(true, q, rng, 1e-5, 2e-5, INSTRUMENT, [0.01, 0.02, 0.1, 0.3, -0.2, 0.4],
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
    T = frame_matrix(v)
    assert np.allclose(T, xyzrpy_to_matrix([0.1, -0.2, 0.3, 0.6, -0.5, 0.4]))
    assert np.allclose(frame_values(T), v)
    assert np.allclose(instrument_values([0.1, -0.2, 0.3, 0.6, -0.5, 0.4]), v)
    E = frame_rotation_axes(v)
    h = 1e-6
    for c, k in enumerate((3, 4, 5)):
        e = np.zeros(6)
        e[k] = h
        dR = (frame_matrix(v + e)[:3, :3] - frame_matrix(v - e)[:3, :3]) / (2 * h)
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
                          [0.01, 0.02, 0.1, 0.3, -0.2, 0.4])][which]
    guess = blk.initial_guess(true)
    assert np.allclose(guess[:6], instrument_values(INSTRUMENT), atol=1e-9)
    r, _, _ = blk.evaluate(true, guess, jacobian=False)
    assert np.abs(r).max() * 1e-5 < 1e-10          # metres


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
        stack(load_robot("puma560"), [PositionMeasurement(np.zeros((3, 5)), np.zeros((3, 3)))])
    b = PositionMeasurement(q, np.zeros((3, 3)))
    with pytest.raises(KincalError, match="both named"):
        stack(load_robot("puma560"), [b, b])


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
