"""Artifact measurement block: analytic Jacobians, exact residuals, noise model, identifiability.

Truth is independent of the code under test: Jacobians against central finite
differences, residuals on configurations that seat the tip exactly (solved by IK on
the true robot), the propagated standard deviations against a Monte Carlo of encoder
noise, and the invariances of distances (base frame, rotations about the probe axis)
against what the identifiability analysis reports by name.
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.identifiability import analyze
from kincal.identify.solver import calibrate
from kincal.measure.artifacts import ArtifactGeometry, ArtifactMeasurement, Probe
from kincal.measure.artifacts.coincidence import Contrasts, Sites
from kincal.measure.artifacts.simulate import simulate_artifact
from kincal.measure.base import stack
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


PROBES = [Probe.length(0.1, True), Probe.vector([0.01, -0.02, 0.12], True), Probe.tool(),
          Probe.length(0.1)]


def _fd_check(block: ArtifactMeasurement, robot, x: np.ndarray, h: float = 1e-6) -> None:
    r0, Jr, Je = block.evaluate(robot, x)
    assert Jr.shape == (r0.size, robot.num_params) and Je.shape == (r0.size, x.size)
    assert len(block.residual_owner()) == r0.size
    fd = np.zeros_like(Jr)
    for k in range(robot.num_params):
        p = robot.param_values.copy()
        p[k] += h
        rp = block.evaluate(robot.with_params(p), x, False)[0]
        p[k] -= 2 * h
        rm = block.evaluate(robot.with_params(p), x, False)[0]
        fd[:, k] = (rp - rm) / (2 * h)
    scale = np.abs(Jr).max()
    # central differences err by ~h^2 * third derivative + rounding ~ eps |r| / h
    np.testing.assert_allclose(Jr, fd, atol=1e-6 * scale)
    fe = np.zeros_like(Je)
    for k in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        fe[:, k] = (block.evaluate(robot, xp, False)[0] - block.evaluate(robot, xm, False)[0]) \
            / (2 * h)
    if Je.size:
        np.testing.assert_allclose(Je, fe, atol=1e-6 * max(np.abs(Je).max(), 1.0))


@pytest.mark.parametrize("probe", PROBES, ids=lambda p: f"{p.mode}-{p.estimate}")
@pytest.mark.parametrize("sockets", ["eliminate", "parameters"])
def test_jacobians_match_central_differences(puma, probe, sockets):
    rng = np.random.default_rng(1)
    q = random_configurations(puma, 14, rng)
    placement = [0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 2]
    socket = list("AABCDABCDABCDD")          # A twice in 0, D twice in 2: coincidence
    g = ArtifactGeometry.cross_bar(0.3, 1e-5, 1e-4)
    b = ArtifactMeasurement(q, placement, socket, g, probe, sockets, "cross",
                            joint_std=1e-5, point_std=1e-5, robot=puma)
    x = b.initial_guess(puma) + 1e-2 * rng.standard_normal(len(b.parameters()))
    _fd_check(b, puma, x)


def test_helmert_contrasts_are_orthonormal_and_keep_the_spread():
    rng = np.random.default_rng(2)
    labels = list("aabacbbbca")
    sites = Sites.from_labels(["p"] * len(labels), labels)
    C = Contrasts.build(sites)
    H = C.apply(np.eye(len(labels)))                       # (K, N) contrast matrix
    assert H.shape == (len(labels) - sites.S, len(labels))
    np.testing.assert_allclose(H @ H.T, np.eye(H.shape[0]), atol=1e-12)
    X = rng.standard_normal((len(labels), 3))
    means = np.array([X[sites.index == k].mean(0) for k in range(sites.S)])
    np.testing.assert_allclose(np.sum(C.apply(X) ** 2), np.sum((X - means[sites.index]) ** 2),
                               rtol=1e-12)
    s2 = rng.uniform(0.5, 2.0, len(labels))
    np.testing.assert_allclose(C.variance(s2), (H**2) @ s2, rtol=1e-12)


def test_residuals_vanish_on_exactly_seated_readings(puma):
    rng = np.random.default_rng(3)
    true = perturb_robot(puma, rng)
    for sockets, visits in (("eliminate", 1), ("parameters", 3), ("eliminate", 3)):
        g = ArtifactGeometry.cross_bar(0.25)
        b, sim = simulate_artifact(true, g, 3, rng, Probe.length(0.08), visits=visits,
                                   sockets=sockets, point_std=0.0, joint_std=0.0)
        exact = b.replace(q=sim.q_true, point_std=1e-5)
        x = exact.initial_guess(true)
        errs = exact.errors(true, x)
        assert np.max(np.abs(errs["distance_m"])) < 1e-9
        assert np.max(np.abs(errs["perpendicularity_rad"])) < 1e-9
        if "coincidence_m" in errs:
            assert np.max(errs["coincidence_m"]) < 1e-9
        # the nominal model does not seat them: errors of the order of the robot errors
        assert np.max(np.abs(exact.errors(puma, exact.initial_guess(puma))["distance_m"])) \
            > 1e-4


def test_propagated_sigmas_match_a_monte_carlo_of_encoder_noise(puma):
    rng = np.random.default_rng(4)
    g = ArtifactGeometry.cross_bar(0.3)
    b, sim = simulate_artifact(puma, g, 3, rng, Probe.length(0.1))
    sd = np.radians(0.01)
    noisy = b.replace(joint_std=sd, point_std=0.0, robot=puma)
    draws = 4000
    # all draws at once: draw i is placement "i.p" of one big block
    q = np.tile(sim.q_true, (draws, 1))
    q = q + sd * rng.standard_normal(q.shape)
    labels = [f"{i}.{p}" for i in range(draws) for p in b.placement_labels]
    big = ArtifactMeasurement(q, labels, b.socket_labels * draws, g, b.probe)
    L = big.lengths(puma).value.reshape(draws, -1)
    A = np.sin(big.angles(puma).value).reshape(draws, -1)      # the cosine residual
    # the standard deviation of a sample std is ~ std / sqrt(2 n): 1.1 % for n = 4000
    np.testing.assert_allclose(L.std(0), noisy.sigma_distance, rtol=0.05)
    np.testing.assert_allclose(A.std(0), noisy.sigma_angle, rtol=0.05)


def test_distances_are_blind_to_the_base_frame_and_rotations_about_the_probe(puma):
    rng = np.random.default_rng(5)
    b, _ = simulate_artifact(puma, ArtifactGeometry.cross_bar(0.3), 12, rng,
                             Probe.length(0.1), joint_std=np.radians(0.001))
    prob, theta = stack(puma, [b])
    _, J = prob.residuals_and_jacobian(theta)
    rep = analyze(J, prob.names, roles=prob.roles)
    base = [f"base.{f}" for f in ("x", "y", "z", "rz", "ry", "rx")]
    # a rigid motion of all points and a turn of the probe about its own axis
    for n in base + ["theta_offset[1]", "d[1]", "theta_offset[6]", "tool.rz"]:
        assert n in rep.unobservable, n
    text = " ".join(rep.describe())
    assert "base.rz does not affect these measurements" in text
    assert all(np.isfinite(rep.column_scale))


def test_coincidence_puts_whole_body_turns_on_the_socket_frames(puma):
    """With several seatings per socket the base angles are not zero columns (the
    residual vectors turn with them) but the socket frames take their place."""
    rng = np.random.default_rng(6)
    g = ArtifactGeometry.two_socket(0.05)
    for sockets in ("eliminate", "parameters"):
        b, _ = simulate_artifact(perturb_robot(puma, rng), g, 3, rng, Probe.length(0.1),
                                 visits=6, sockets=sockets, point_std=2e-5)
        res = calibrate(puma, [b])
        for n in ("base.rz", "base.ry", "base.rx", "theta_offset[1]"):
            assert n not in res.estimated
            assert n in res.identifiability.dependent, n
            assert any(".hole_0.r" in d or ".hole_1.r" in d
                       for d in res.identifiability.dependent[n]), n
        assert np.all(np.isfinite(res.std)) and res.sigma0 < 2.0


def test_artifact_blocks_mix_with_position_data_in_one_solver_call(puma):
    rng = np.random.default_rng(7)
    true = perturb_robot(puma, rng)
    cross, _ = simulate_artifact(true, ArtifactGeometry.cross_bar(0.3), 10, rng,
                                 Probe.length(0.1), joint_std=np.radians(0.001), name="cross")
    q = random_configurations(puma, 15, rng)
    tracker = simulate_positions(true, q, rng, 2e-5, instrument=[1.5, 0.2, 0.1, 0, 0, 0.3])
    res = calibrate(puma, [cross, tracker])
    assert res.converged
    # the tracker sees the base frame (up to its own frame), the cross adds length data
    assert "a[2]" in res.estimated and res.sigma0 < 2.0
    assert {"distance_m", "perpendicularity_rad", "position_m"} <= set(
        k[4:] for k in res.rms())


def test_bad_inputs_are_one_line_errors(puma):
    q = np.zeros((2, 6))
    g = ArtifactGeometry.cross_bar(0.3)
    with pytest.raises(KincalError, match="row 2 names socket 'E'"):
        ArtifactMeasurement(q, [1, 1], ["A", "E"], g, Probe.length(0.1))
    with pytest.raises(KincalError, match="needs the robot"):
        ArtifactMeasurement(q, [1, 1], ["A", "C"], g, Probe.length(0.1), joint_std=1e-5)
    with pytest.raises(KincalError, match="socket mode"):
        ArtifactMeasurement(q, [1, 1], ["A", "C"], g, Probe.length(0.1), sockets="mean")
    with pytest.raises(KincalError, match="probe"):
        Probe("tool", (), True)
    with pytest.raises(KincalError, match="unknown socket"):
        ArtifactGeometry("custom", ("A", "B"), (
            ArtifactGeometry.cross_bar(1.0).distances[0],))
    with pytest.raises(KincalError, match="zero uncertainty"):
        ArtifactMeasurement(q, [1, 1], ["A", "C"], g, Probe.length(0.1), point_std=0.0)
