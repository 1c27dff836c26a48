"""Per-axis standard deviations of pose files are true weights: ``1/sigma^2`` per
instrument axis and row for positions, the covariance ``E diag(s^2) E^T`` of the stated
angles for rotations.  Checked against closed forms (the weighted least-squares estimate
of a linear sub-problem, the rotation axes of an intrinsic x-y'-z'' Euler set, the
whitened objective) and, by Monte Carlo on a simulated robot with heteroscedastic noise,
standard errors that match the scatter and estimates better than unweighted ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.identify.solver import calibrate
from kincal.measure.instruments.pose import PoseMeasurement, simulate_poses
from kincal.measure.orientation import Orientation, angle_axes
from kincal.measure.registry import read_measurements
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot
from kincal.spatial import log_so3, rotx, roty

INSTRUMENT = [1.4, -0.6, 0.3, 0.0, 0.0, 0.0]            # x y z rz ry rx: axes of the base
TARGET = [0.02, -0.01, 0.09, 0.0, 0.0, 0.0]
TRIALS = 20


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _heteroscedastic(robot, true, q, rng, sp):
    """Poses of ``true`` with position noise N(0, sp[i, k]^2) per row i and axis k."""
    exact = simulate_poses(true, q, rng, 0.0, 0.0, INSTRUMENT, TARGET)
    P = exact.poses.copy()
    P[:, :3, 3] += sp * rng.standard_normal(sp.shape)
    return P


def test_euler_axes_match_the_closed_form():
    """Intrinsic x-y'-z'': ``w = e_x da + Rx(a) e_y db + Rx(a) Ry(b) e_z dc``."""
    a, b, c = np.array([-1.57, 0.4]), np.array([-0.35, 1.1]), np.array([-1.57, 0.2])
    E = angle_axes(Orientation("euler", "XYZ"), {"rx": a, "ry": b, "rz": c})
    ex, ey, ez = np.eye(3)
    for i in range(2):
        want = np.stack([ex, rotx(a[i]) @ ey, rotx(a[i]) @ roty(b[i]) @ ez], axis=1)
        np.testing.assert_allclose(E[i], want, atol=1e-9)


def test_file_sigmas_are_read_per_axis_and_whiten_as_stated(tmp_path: Path, puma):
    rng = np.random.default_rng(3)
    q = random_configurations(puma, 4, rng)
    ang = np.array([[-90.0, -20.0, -90.0], [10.0, 30.0, -40.0], [0, 0, 0], [5, -5, 80]])
    sig = np.array([[0.01, 0.02, 0.05, 0.001, 0.002, 0.004]] * 4) * [[1], [2], [1], [3]]
    head = "# kincal measurements: instrument=pose; orientation=euler:XYZ\n"
    head += ",".join(f"q{j}_rad" for j in range(1, 7)) + ",x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg,"
    head += "sigma_x_mm,sigma_y_mm,sigma_z_mm,sigma_rx_deg,sigma_ry_deg,sigma_rz_deg\n"
    rows = [[*qi, 100, 200, 300, *a, *s] for qi, a, s in zip(q, ang, sig, strict=True)]
    path = tmp_path / "p.csv"
    path.write_text(head + "\n".join(",".join(f"{v:.17g}" for v in r) for r in rows) + "\n")
    (b,) = read_measurements(path, puma)
    np.testing.assert_allclose(b.sigma_position, sig[:, :3] / 1000, rtol=1e-14)
    np.testing.assert_allclose(b.sigma_orientation, np.radians(sig[:, 3:]), rtol=1e-14)
    assert any("per instrument axis" in n for n in b.provenance.table.notes)
    # the whitened objective is sum dy^T diag(1/s^2) dy + e^T C^-1 e, C = E S^2 E^T
    extra = np.concatenate([[0.1, 0.2, 0.3, 0.01, -0.02, 0.03], TARGET])
    r, _, _ = b.evaluate(puma, extra, jacobian=False)
    pred = b.predict(puma, extra)
    dy = pred[:, :3, 3] - b.poses[:, :3, 3]
    e = log_so3(pred[:, :3, :3] @ np.swapaxes(b.poses[:, :3, :3], 1, 2))
    want = 0.0
    for i in range(4):
        a, bb = np.radians(ang[i, 0]), np.radians(ang[i, 1])
        E = np.stack([np.eye(3)[0], rotx(a) @ np.eye(3)[1], rotx(a) @ roty(bb) @ np.eye(3)[2]],
                     axis=1)
        C = E @ np.diag(np.radians(sig[i, 3:]) ** 2) @ E.T
        want += np.sum(dy[i] ** 2 / (sig[i, :3] / 1000) ** 2) + e[i] @ np.linalg.solve(C, e[i])
    assert r @ r == pytest.approx(want, rel=1e-7)
    # the Jacobian of the weighted rows is the derivative of the weighted residuals
    r0, Jr, Je = b.evaluate(puma, extra)
    h = 1e-7
    for k in (0, 4, 9):
        d = np.zeros(12)
        d[k] = h
        fd = (b.evaluate(puma, extra + d, False)[0] - b.evaluate(puma, extra - d, False)[0])
        np.testing.assert_allclose(Je[:, k], fd / (2 * h), rtol=1e-5,
                                   atol=1e-6 * np.abs(Je[:, k]).max())
    np.testing.assert_allclose(r0, r, rtol=1e-12)
    # a quaternion has no angles to state per-angle sigmas for: one error line
    qhead = head.replace("rx_deg,ry_deg,rz_deg", "qw,qx,qy,qz").replace(
        "; orientation=euler:XYZ", "")
    qrows = [[*qi, 100, 200, 300, 1, 0, 0, 0, *s] for qi, s in zip(q, sig, strict=True)]
    path.write_text(qhead + "\n".join(",".join(f"{v:.17g}" for v in r) for r in qrows) + "\n")
    with pytest.raises(MeasurementFileError, match="not a quaternion"):
        read_measurements(path, puma)


def test_weighted_translation_is_the_closed_form_weighted_mean(puma):
    """With the robot and the frames' rotations known, the instrument position enters
    linearly (``y = p_e + a - t_I``): its estimate is the weighted mean per axis,
    ``t_k = sum w_ik d_ik / sum w_ik`` with ``w = 1/s^2``, standard error
    ``1/sqrt(sum w_ik)``."""
    rng = np.random.default_rng(5)
    q = random_configurations(puma, 25, rng)
    sp = np.exp(rng.uniform(np.log(2e-6), np.log(2e-4), (25, 3)))
    P = _heteroscedastic(puma, puma, q, rng, sp)
    blk = PoseMeasurement(q, P, sp, 1e-3, "tracker")
    free = ["tracker.x", "tracker.y", "tracker.z"]
    res = calibrate(puma, [blk], free=free, initial={"tracker.target." + c: v for c, v in
                                                     zip(("x", "y", "z"), TARGET[:3],
                                                         strict=True)},
                    trust_sigma=True)
    T = puma.fk(q)
    exact = T[:, :3, 3] + T[:, :3, :3] @ np.asarray(TARGET[:3])    # p_e + R_e t_t
    w = 1.0 / sp**2
    want = np.sum(w * (exact - P[:, :3, 3]), axis=0) / np.sum(w, axis=0)
    idx = [res.names.index(n) for n in free]
    np.testing.assert_allclose(res.theta[idx], want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.std[idx], 1.0 / np.sqrt(np.sum(w, axis=0)), rtol=1e-6)


def test_monte_carlo_standard_errors_are_honest_and_beat_unweighted(puma):
    rng = np.random.default_rng(11)
    true = perturb_robot(puma, rng)
    q = random_configurations(puma, 30, rng)
    sp = np.exp(rng.uniform(np.log(3e-6), np.log(3e-4), (30, 3)))   # 100x between rows/axes
    est_w, est_u, std_w = [], [], []
    for _ in range(TRIALS):
        P = _heteroscedastic(puma, true, q, rng, sp)
        fw = calibrate(puma, [PoseMeasurement(q, P, sp, 1e-3)], trust_sigma=True)
        fu = calibrate(puma, [PoseMeasurement(q, P, np.sqrt(np.mean(sp**2)), 1e-3)],
                       trust_sigma=True)
        assert fw.estimated == fu.estimated
        est_w.append(fw.theta)
        est_u.append(fu.theta)
        std_w.append(fw.std)
    idx = [fw.names.index(n) for n in fw.estimated]
    scatter_w = np.var(np.array(est_w)[:, idx], axis=0, ddof=1)
    scatter_u = np.var(np.array(est_u)[:, idx], axis=0, ddof=1)
    stated = np.mean(np.array(std_w)[:, idx] ** 2, axis=0)
    # honest: the stated variance matches the scatter over trials; the mean ratio over
    # the parameters of a variance estimated from TRIALS draws is 1 within ~ 0.3
    assert 0.7 < float(np.mean(scatter_w / stated)) < 1.4
    # unweighted estimates scatter more than weighted ones (Gauss-Markov)
    assert float(np.mean(scatter_u / scatter_w)) > 2.0
