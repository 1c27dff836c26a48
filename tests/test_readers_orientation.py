"""Orientation conventions of pose files, each checked against
``scipy.spatial.transform.Rotation`` (an independent implementation), through the file
reader; per-axis standard deviations kept per axis."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kincal.errors import MeasurementFileError
from kincal.measure.orientation import Orientation, parse_orientation, rotation_matrices
from kincal.measure.registry import read_measurements
from kincal.robots.files import load_serial_robot

JOINTS = "q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad"
SEQUENCES = ["".join(p) for p in itertools.permutations("xyz")]


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


def _pose_file(tmp_path: Path, cols: list[str], rows: np.ndarray, tags: str = "") -> Path:
    p = tmp_path / "pose.csv"
    q = np.zeros((len(rows), 6))
    text = f"# kincal measurements: instrument=pose{tags}\n{JOINTS},x_mm,y_mm,z_mm,"
    text += ",".join(cols) + "\n"
    text += "\n".join(",".join(f"{v:.17g}" for v in [*qi, 1, 2, 3, *r])
                      for qi, r in zip(q, rows, strict=True)) + "\n"
    p.write_text(text)
    return p


@pytest.mark.parametrize("seq", SEQUENCES + [s.upper() for s in SEQUENCES])
def test_euler_sequences_match_scipy(tmp_path, puma, seq):
    rng = np.random.default_rng(7)
    ang = rng.uniform(-170, 170, (8, 3))            # columns rx, ry, rz [deg]
    ang[:, 1] = rng.uniform(-80, 80, 8)
    p = _pose_file(tmp_path, ["rx_deg", "ry_deg", "rz_deg"], ang, f"; orientation=euler:{seq}")
    (b,) = read_measurements(p, puma)
    by_seq = np.stack([ang[:, "xyz".index(c)] for c in seq.lower()], axis=1)
    want = Rotation.from_euler(seq, by_seq, degrees=True).as_matrix()
    np.testing.assert_allclose(b.poses[:, :3, :3], want, rtol=0, atol=1e-13)
    np.testing.assert_allclose(b.poses[:, :3, 3], np.tile([1e-3, 2e-3, 3e-3], (8, 1)))


def test_rpy_is_the_default_and_is_extrinsic_xyz(tmp_path, puma):
    ang = np.array([[10.0, -20.0, 30.0], [170, 80, -120]])
    for tags in ("", "; orientation=rpy"):
        (b,) = read_measurements(_pose_file(tmp_path, ["rx_deg", "ry_deg", "rz_deg"], ang,
                                            tags), puma)
        want = Rotation.from_euler("xyz", ang, degrees=True).as_matrix()
        np.testing.assert_allclose(b.poses[:, :3, :3], want, atol=1e-13)


def test_rotation_vectors_match_scipy(tmp_path, puma):
    rng = np.random.default_rng(8)
    rv = rng.normal(0, 1.2, (6, 3))
    (b,) = read_measurements(_pose_file(tmp_path, ["rx_rad", "ry_rad", "rz_rad"], rv,
                                        "; orientation=rotvec"), puma)
    np.testing.assert_allclose(b.poses[:, :3, :3], Rotation.from_rotvec(rv).as_matrix(),
                               atol=1e-13)


@pytest.mark.parametrize("order", [("qx", "qy", "qz", "qw"), ("qw", "qx", "qy", "qz")])
def test_quaternion_columns_in_either_order_match_scipy(tmp_path, puma, order):
    rng = np.random.default_rng(9)
    quat = Rotation.random(5, random_state=rng).as_quat()          # scipy: x, y, z, w
    quat[0] *= 1.0004                                              # within the tolerance
    cols = {"qx": quat[:, 0], "qy": quat[:, 1], "qz": quat[:, 2], "qw": quat[:, 3]}
    rows = np.stack([cols[c] for c in order], axis=1)
    (b,) = read_measurements(_pose_file(tmp_path, list(order), rows), puma)
    np.testing.assert_allclose(b.poses[:, :3, :3], Rotation.from_quat(quat).as_matrix(),
                               atol=1e-13)


def test_quaternion_far_from_unit_norm_names_its_line(tmp_path, puma):
    rows = np.array([[0, 0, 0, 1.0], [0, 0, 0, 1.1]])
    with pytest.raises(MeasurementFileError, match=r"line 4: the quaternion's norm is 1.1, "
                       "not 1"):
        read_measurements(_pose_file(tmp_path, ["qx", "qy", "qz", "qw"], rows), puma)


@pytest.mark.parametrize("text,msg", [
    ("euler:ZYZ", "proper Euler sequence"), ("euler:XyZ", "upper case"),
    ("euler:XY", "three of x, y, z"), ("yaw-pitch-roll", "is not a convention")])
def test_bad_conventions_are_refused(tmp_path, puma, text, msg):
    with pytest.raises(MeasurementFileError, match=msg):
        parse_orientation(text)
    p = _pose_file(tmp_path, ["rx_deg", "ry_deg", "rz_deg"], np.zeros((1, 3)),
                   f"; orientation={text}")
    with pytest.raises(MeasurementFileError, match=r"pose.csv: line 1: orientation"):
        read_measurements(p, puma)


def test_matrix_order_of_intrinsic_and_extrinsic():
    assert Orientation("euler", "ZYX").matrix_order() == "zyx"
    assert Orientation("euler", "xyz").matrix_order() == "zyx"
    a = {"rx": np.array([0.3]), "ry": np.array([-0.2]), "rz": np.array([1.1])}
    np.testing.assert_allclose(rotation_matrices(Orientation("euler", "ZYX"), a),
                               rotation_matrices(Orientation(), a), atol=1e-15)


def test_per_axis_sigmas_are_kept_per_axis(tmp_path, puma):
    ang = np.zeros((2, 3))
    sig = np.array([[0.01, 0.02, 0.02, 0.001, 0.002, 0.002],
                    [0.03, 0.03, 0.03, 0.004, 0.004, 0.004]])
    cols = ["rx_deg", "ry_deg", "rz_deg", "sigma_x_mm", "sigma_y_mm", "sigma_z_mm",
            "sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg"]
    (b,) = read_measurements(_pose_file(tmp_path, cols, np.hstack([ang, sig])), puma)
    np.testing.assert_allclose(b.sigma_position, sig[:, :3] / 1000, rtol=1e-14)
    np.testing.assert_allclose(b.sigma_orientation, np.radians(sig[:, 3:]), rtol=1e-14)
    # rpy at zero: the angles turn about the instrument axes z, y, x (R = Rz Ry Rx)
    np.testing.assert_allclose(b.orientation_axes[0], np.eye(3), atol=1e-9)
    assert any("per instrument axis" in n for n in b.provenance.table.notes)
    with pytest.raises(MeasurementFileError, match="missing 'sigma_z'"):
        read_measurements(_pose_file(tmp_path, cols[:5], np.hstack([ang, sig[:, :2]])), puma)
