"""The built-in robot library, checked against computations that do not use kincal.

* Forward kinematics of every library robot equals a hand computation: the YAML is read
  with ``yaml.safe_load`` (not kincal's loader), units are converted here, and the link
  matrices are written out entry by entry (standard DH, Craig's modified DH, Hayati's
  extra ``Ry(beta)``; base and tool as ``Trans Rz Ry Rx``).
* Published models the DH tables were derived from (ROS-Industrial URDFs of the IRB 120
  and the KR 6 R900 sixx, the Motoman dataset's DH table with its reflector link, the
  closed form of the spherical arm) give the same poses.
* Every analytic derivative (geometric Jacobian in base and tool frame, analytic
  Jacobian for ZYZ and RPY angles, parameter Jacobian) equals central finite differences,
  with random non-zero base and tool frames.
* The DH, modified-DH and elementary-transform forms of each robot agree, and YAML
  write/read round trips preserve everything.
* ``kincal robots`` and ``kincal show`` work for every library robot.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from kincal.cli import app
from kincal.robots.dh import standard_to_modified
from kincal.robots.files import (
    library_dir,
    library_names,
    load_serial_robot,
    read_robot_yaml,
    robot_from_dict,
    write_robot_yaml,
)

LENGTH = {"m": 1.0, "mm": 1e-3}
ANGLE = {"rad": 1.0, "deg": math.pi / 180.0}
DH_CONVENTIONS = ("standard_dh", "modified_dh", "hayati")
FRAME_KEYS = ("x", "y", "z", "rx", "ry", "rz")

FK_TOL = 1e-12          # absolute, on every entry of T (metres and rotation entries)
FD_TOL = 1e-6           # |J - J_fd| <= FD_TOL * max(1, |J|), entry by entry
FD_STEP = 1e-6          # central differences [m or rad]


def _doc(name: str) -> dict:
    return yaml.safe_load((library_dir() / f"{name}.yaml").read_text(encoding="utf-8"))


SERIAL = [n for n in library_names() if _doc(n).get("kind") != "fivebar"]
STANDARD = [n for n in SERIAL if _doc(n)["convention"] == "standard_dh"]
REQUIRED = {"puma560", "puma560_hayati", "stanford", "spherical_rrp", "scara", "ur5", "irb120",
            "kr6", "panda", "motoman_right", "motoman_left"}


def _rng(name: str, salt: int = 0) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32(name.encode()) + salt)


# --------------------------------------------------------------------------- hand kinematics
def _mat(rows: list[list], n: int) -> np.ndarray:
    """Stack a 4x4 nested list of scalars / (N,) arrays into (N, 4, 4)."""
    return np.stack([np.stack([np.broadcast_to(np.asarray(e, float), (n,)) for e in r], -1)
                     for r in rows], -2)


def dh_standard(theta, d, a, alpha, n):
    """A = Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return _mat([[ct, -st * ca, st * sa, a * ct],
                 [st, ct * ca, -ct * sa, a * st],
                 [0.0, sa, ca, d],
                 [0.0, 0.0, 0.0, 1.0]], n)


def dh_modified(theta, d, a, alpha, n):
    """Craig: A = Rx(alpha) Tx(a) Rz(theta) Tz(d)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return _mat([[ct, -st, 0.0, a],
                 [st * ca, ct * ca, -sa, -sa * d],
                 [st * sa, ct * sa, ca, ca * d],
                 [0.0, 0.0, 0.0, 1.0]], n)


def hayati_ry(beta, n):
    cb, sb = np.cos(beta), np.sin(beta)
    return _mat([[cb, 0.0, sb, 0.0], [0.0, 1.0, 0.0, 0.0], [-sb, 0.0, cb, 0.0],
                 [0.0, 0.0, 0.0, 1.0]], n)


def xyz_rpy(x, y, z, rx, ry, rz, n):
    """Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)."""
    cx, sx, cy, sy, cz, sz = (np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz),
                              np.sin(rz))
    return _mat([[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx, x],
                 [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx, y],
                 [-sy, cy * sx, cy * cx, z],
                 [0.0, 0.0, 0.0, 1.0]], n)


def _scales(doc: dict) -> tuple[float, float]:
    return LENGTH[doc["units"]["length"]], ANGLE[doc["units"]["angle"]]


def _frame(doc: dict, key: str, n: int) -> np.ndarray:
    ls, as_ = _scales(doc)
    f = doc.get(key) or {}
    v = [float(f.get(k, 0.0)) * (ls if i < 3 else as_) for i, k in enumerate(FRAME_KEYS)]
    return xyz_rpy(*v, n)


def hand_fk(doc: dict, q: np.ndarray) -> np.ndarray:
    """Forward kinematics from the YAML document alone: (N, n) -> (N, 4, 4)."""
    ls, as_ = _scales(doc)
    conv = doc["convention"]
    n = q.shape[0]
    T = _frame(doc, "base", n)
    for i, row in enumerate(doc["joints"]):
        theta = float(row.get("theta_offset", 0.0)) * as_
        d = float(row["d"]) * ls
        a, alpha = float(row["a"]) * ls, float(row["alpha"]) * as_
        if row["type"] == "revolute":
            theta = theta + q[:, i]
        else:
            d = d + q[:, i]
        if conv == "modified_dh":
            A = dh_modified(theta, d, a, alpha, n)
        else:
            A = dh_standard(theta, d, a, alpha, n)
            if "beta" in row:
                A = A @ hayati_ry(float(row["beta"]) * as_, n)
        T = T @ A
    return T @ _frame(doc, "tool", n)


def doc_limits(doc: dict) -> np.ndarray:
    """(n, 2) limits in SI from the document; unlimited revolute joints get [-pi, pi]."""
    ls, as_ = _scales(doc)
    out = []
    for row in doc["joints"]:
        rev = row["type"] == "revolute"
        if row.get("limits") is None:
            assert rev, f"prismatic joint {row['name']} has no limits"
            out.append([-math.pi, math.pi])
        else:
            s = as_ if rev else ls
            out.append([row["limits"][0] * s, row["limits"][1] * s])
    return np.array(out)


def random_q(doc: dict, rng: np.random.Generator, n: int) -> np.ndarray:
    lim = doc_limits(doc)
    return lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((n, len(lim)))


def framed(name: str):
    """The library robot with random non-zero base and tool frames."""
    rng = _rng(name, 1)
    vals = {}
    for prefix in ("base", "tool"):
        for k, v in zip(FRAME_KEYS, np.r_[rng.uniform(-0.5, 0.5, 3), rng.uniform(-1, 1, 3)],
                        strict=True):
            vals[f"{prefix}.{k}"] = v
    return load_serial_robot(name).with_params(vals)


def _max_err(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.max(np.abs(A - B)))


# --------------------------------------------------------------------------- the files
def test_library_holds_the_required_robots():
    assert REQUIRED <= set(SERIAL), sorted(REQUIRED - set(SERIAL))


@pytest.mark.parametrize("name", SERIAL)
def test_file_documents_its_numbers(name):
    doc = _doc(name)
    assert doc["name"] == name
    for key in ("description", "source", "units", "convention"):
        assert str(doc.get(key, "")).strip(), f"{name}: missing {key}"
    assert doc["units"]["length"] in LENGTH and doc["units"]["angle"] in ANGLE
    robot = load_serial_robot(name)
    for key in ("description", "source", "notes"):
        assert robot.meta.get(key) == (str(doc[key]).strip() if key in doc else None)
    assert [j.name for j in robot.joints] == [r["name"] for r in doc["joints"]]
    assert [j.kind for j in robot.joints] == [r["type"] for r in doc["joints"]]
    lim = doc_limits(doc)
    for j, row, (lo, hi) in zip(robot.joints, doc["joints"], lim, strict=True):
        if row.get("limits") is None:
            assert j.lower == -math.inf and j.upper == math.inf
        else:
            assert (j.lower, j.upper) == pytest.approx((lo, hi), rel=1e-15, abs=0)


# --------------------------------------------------------------------------- forward kinematics
@pytest.mark.parametrize("name", SERIAL)
def test_fk_equals_hand_computation(name):
    doc = _doc(name)
    if doc["convention"] not in DH_CONVENTIONS:
        pytest.skip(f"no hand computation for convention {doc['convention']}")
    rng = _rng(name)
    q = random_q(doc, rng, 25)
    robot = load_serial_robot(name)
    assert _max_err(robot.fk(q), hand_fk(doc, q)) <= FK_TOL
    assert _max_err(robot.fk(q[0]), hand_fk(doc, q[:1])[0]) <= FK_TOL

    # The same with every number of the file perturbed (non-zero offsets, betas, frames).
    ls, as_ = _scales(doc)
    pert = yaml.safe_load(yaml.safe_dump(doc))
    for row in pert["joints"]:
        for key in ("a", "d", "alpha", "theta_offset", "beta"):
            if key in row or key == "theta_offset":
                scale = ls if key in ("a", "d") else as_
                row[key] = float(row.get(key, 0.0)) + rng.uniform(-0.05, 0.05) / scale
    for key in ("base", "tool"):
        pert[key] = {k: rng.uniform(-0.3, 0.3) / (ls if i < 3 else as_)
                     for i, k in enumerate(FRAME_KEYS)}
    other = robot_from_dict(pert, f"{name} (perturbed)")
    assert _max_err(other.fk(q), hand_fk(pert, q)) <= FK_TOL


def test_spherical_arm_spherical_arm_closed_form():
    doc = _doc("spherical_rrp")
    d2 = doc["joints"][1]["d"] * LENGTH[doc["units"]["length"]]
    assert d2 == 1.0
    robot = load_serial_robot("spherical_rrp")
    assert [j.kind for j in robot.joints] == ["revolute", "revolute", "prismatic"]
    q = random_q(doc, _rng("spherical"), 50)
    r2 = math.sqrt(2.0)
    q = np.vstack([q, [0.0, math.pi / 4, 0.5], [math.pi / 4, 0.0, 0.1]])
    t1, t2, d3 = q.T
    c1, s1, c2, s2 = np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2)
    p = np.stack([c1 * s2 * d3 - d2 * s1, s1 * s2 * d3 + d2 * c1, c2 * d3], -1)
    P = robot.fk(q)[:, :3, 3]
    assert _max_err(P, p) <= FK_TOL
    # The report's endpoints: p_i = p(q(0)), p_f reached at q_f.
    assert _max_err(P[-2], np.array([r2 / 4, 1.0, r2 / 4])) <= FK_TOL
    assert _max_err(P[-1], np.array([-r2 / 2, r2 / 2, 0.1])) <= FK_TOL


def urdf_fk(origins, axes, tool_rpy, q):
    """Serial URDF chain with zero-rpy joint origins: prod Trans(o_i) Rot(axis_i, q_i), tool."""
    n = q.shape[0]
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i, (o, k) in enumerate(zip(origins, axes, strict=True)):
        k = np.asarray(k, float)
        c, s = np.cos(q[:, i]), np.sin(q[:, i])
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + s[:, None, None] * K + (1 - c)[:, None, None] * (K @ K)   # Rodrigues
        A = np.zeros((n, 4, 4))
        A[:, :3, :3] = R
        A[:, :3, 3] = o
        A[:, 3, 3] = 1.0
        T = T @ A
    return T @ xyz_rpy(0.0, 0.0, 0.0, *tool_rpy, n)


def test_irb120_equals_ros_industrial_urdf():
    # abb_irb120_support/urdf/irb120_3_58_macro.xacro: joint origins [m] and axes; tool0 =
    # flange * rpy(0, pi/2, 0).
    origins = [(0, 0, 0), (0, 0, 0.29), (0, 0, 0.27), (0, 0, 0.07), (0.302, 0, 0), (0.072, 0, 0)]
    axes = [(0, 0, 1), (0, 1, 0), (0, 1, 0), (1, 0, 0), (0, 1, 0), (1, 0, 0)]
    limits = np.radians([[-165, 165], [-110, 110], [-110, 70], [-160, 160], [-120, 120],
                         [-400, 400]])
    robot = load_serial_robot("irb120")
    np.testing.assert_allclose(robot.joint_limits, limits, rtol=1e-15)
    q = random_q(_doc("irb120"), _rng("irb120 urdf"), 25)
    q = np.vstack([np.zeros(6), q])
    assert _max_err(robot.fk(q), urdf_fk(origins, axes, (0, math.pi / 2, 0), q)) <= FK_TOL
    # ABB's product specification: flange (tool0) at (374, 0, 630) mm at the calibration position.
    assert _max_err(robot.fk(np.zeros(6))[:3, 3], np.array([0.374, 0.0, 0.630])) <= FK_TOL


def test_kr6_equals_ros_industrial_urdf():
    # kuka_kr6_support/urdf/kr6r900sixx_macro.xacro: joint origins [m] and axes (A1, A4, A6
    # turn about negative axes); tool0 ($FLANGE) = link_6 * rpy(0, pi/2, 0).
    origins = [(0, 0, 0.4), (0.025, 0, 0), (0.455, 0, 0), (0, 0, 0.035), (0.42, 0, 0),
               (0.08, 0, 0)]
    axes = [(0, 0, -1), (0, 1, 0), (0, 1, 0), (-1, 0, 0), (0, 1, 0), (-1, 0, 0)]
    limits = np.radians([[-170, 170], [-190, 45], [-120, 156], [-185, 185], [-120, 120],
                         [-350, 350]])
    robot = load_serial_robot("kr6")
    np.testing.assert_allclose(robot.joint_limits, limits, rtol=1e-15)
    q = random_q(_doc("kr6"), _rng("kr6 urdf"), 25)
    q = np.vstack([np.zeros(6), np.radians([0, -90, 90, 0, 0, 0]), q])
    assert _max_err(robot.fk(q), urdf_fk(origins, axes, (0, math.pi / 2, 0), q)) <= FK_TOL


# The Motoman dataset's nominal standard-DH table (data/motoman_leica/nominal_dh.yaml, columns
# a, d, alpha, theta_offset [m, rad]) and its fixed reflector link [a, d, alpha, theta].
_MOTOMAN_ARM = [[0.150, 1.4159, -math.pi / 2, 0.0],
                [0.614, 0.000, math.pi, -math.pi / 2],
                [0.200, 0.000, -math.pi / 2, 0.0],
                [0.000, -0.640, math.pi / 2, 0.0],
                [0.030, 0.000, math.pi / 2, -math.pi / 2],
                [0.000, 0.200, 0.0, 0.0]]
MOTOMAN = {
    "motoman_right": ([[0.0, -0.263, math.radians(15), -math.pi / 2]] + _MOTOMAN_ARM,
                      [0.045, 0.245, 0.0, -0.38]),
    "motoman_left": ([[0.0, -0.263, -math.radians(15), -math.pi / 2]] + _MOTOMAN_ARM,
                     [0.05, 0.25, 0.0, 0.0]),
}


@pytest.mark.parametrize("name", sorted(MOTOMAN))
def test_motoman_equals_dataset_dh_with_reflector_link(name):
    table, (ra, rd, ralpha, rtheta) = MOTOMAN[name]
    robot = load_serial_robot(name)
    assert robot.joint_names == ("E", "S", "L", "U", "R", "B", "T")
    q = _rng(name).uniform(-math.pi, math.pi, (25, 7))
    T = np.broadcast_to(np.eye(4), (25, 4, 4))
    for (a, d, alpha, off), qi in zip(table, q.T, strict=True):
        T = T @ dh_standard(off + qi, d, a, alpha, 25)
    T = T @ dh_standard(rtheta, rd, ra, ralpha, 25)
    assert _max_err(robot.fk(q), T) <= FK_TOL


def test_panda_flange_at_zero():
    # q = 0: x = a4 + a5 + a7 = 0.088 m, z = d1 + d3 + d5 - flange = 0.926 m, flange facing down.
    T = load_serial_robot("panda").fk(np.zeros(7))
    assert _max_err(T, np.array([[1, 0, 0, 0.088], [0, -1, 0, 0], [0, 0, -1, 0.926],
                                 [0, 0, 0, 1.0]])) <= FK_TOL


def test_hayati_puma_is_the_puma_plus_a_beta():
    puma, hay = load_serial_robot("puma560"), load_serial_robot("puma560_hayati")
    assert hay.meta["convention"] == "hayati"
    assert hay.param_values[hay.param_index("beta[2]")] == 0.0
    assert [n for n in hay.param_names if n not in puma.param_names] == ["beta[2]"]
    q = random_q(_doc("puma560"), _rng("hayati"), 20)
    assert _max_err(hay.fk(q), puma.fk(q)) <= FK_TOL


# --------------------------------------------------------------------------- derivatives
def _vee(W: np.ndarray) -> np.ndarray:
    return 0.5 * np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0],
                           W[..., 1, 0] - W[..., 0, 1]], -1)


def _fd_twist(Tp, Tm, T, frame="base"):
    """[v; w] from central differences of poses (N, 6); tool frame: rotated by R^T."""
    v = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * FD_STEP)
    dR = (Tp[:, :3, :3] - Tm[:, :3, :3]) / (2 * FD_STEP)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    if frame == "tool":
        return np.concatenate([np.einsum("nij,nj->ni", Rt, v), _vee(Rt @ dR)], -1)
    return np.concatenate([v, _vee(dR @ Rt)], -1)


def _assert_fd(J: np.ndarray, Jfd: np.ndarray, what: str) -> None:
    ratio = np.abs(J - Jfd) / np.maximum(1.0, np.abs(J))
    assert np.all(ratio <= FD_TOL), f"{what}: worst relative error {ratio.max():.2e}"


def _fd_joint(robot, q, fn):
    """Central differences of fn(T) over the joints: (N, m, n)."""
    cols = []
    for i in range(robot.n):
        e = np.zeros(robot.n)
        e[i] = FD_STEP
        cols.append(fn(robot.fk(q + e), robot.fk(q - e)))
    return np.stack(cols, -1)


@pytest.mark.parametrize("name", SERIAL)
def test_geometric_jacobians_equal_finite_differences(name):
    robot = framed(name)
    q = random_q(_doc(name), _rng(name, 2), 6)
    T = robot.fk(q)
    for frame in ("base", "tool"):
        Jfd = _fd_joint(robot, q, lambda Tp, Tm, f=frame: _fd_twist(Tp, Tm, T, f))
        _assert_fd(robot.jacobian(q, frame=frame), Jfd, f"{name} {frame} Jacobian")
    _, J, Jp = robot.fk_with_jacobians(q)
    _assert_fd(J, _fd_joint(robot, q, lambda Tp, Tm: _fd_twist(Tp, Tm, T)), "fk_with_jacobians")
    _assert_fd(robot.jacobian(q[0]), _fd_joint(robot, q, lambda Tp, Tm: _fd_twist(Tp, Tm, T))[0],
               "single-configuration Jacobian")


def zyz_angles(R):
    """(phi, theta, psi) with R = Rz(phi) Ry(theta) Rz(psi), theta in [0, pi]."""
    return np.stack([np.arctan2(R[:, 1, 2], R[:, 0, 2]),
                     np.arctan2(np.hypot(R[:, 0, 2], R[:, 1, 2]), R[:, 2, 2]),
                     np.arctan2(R[:, 2, 1], -R[:, 2, 0])], -1)


def rpy_angles(R):
    """(roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2]."""
    return np.stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]),
                     np.arctan2(-R[:, 2, 0], np.hypot(R[:, 0, 0], R[:, 1, 0])),
                     np.arctan2(R[:, 1, 0], R[:, 0, 0])], -1)


@pytest.mark.parametrize("representation", ["zyz", "rpy"])
@pytest.mark.parametrize("name", SERIAL)
def test_analytic_jacobians_equal_finite_differences(name, representation):
    robot = framed(name)
    angles = zyz_angles if representation == "zyz" else rpy_angles
    q = random_q(_doc(name), _rng(name, 3), 60)
    R = robot.fk(q)[:, :3, :3]
    # Stay away from the representation singularity: sin(theta) resp. cos(pitch) >= 0.2.
    margin = np.sin(angles(R)[:, 1]) if representation == "zyz" else np.cos(angles(R)[:, 1])
    q = q[margin >= 0.2][:6]
    assert len(q) >= 3, "too few configurations away from the representation singularity"

    def diff(Tp, Tm):
        dang = angles(Tp[:, :3, :3]) - angles(Tm[:, :3, :3])
        dang = (dang + math.pi) % (2 * math.pi) - math.pi
        return np.concatenate([Tp[:, :3, 3] - Tm[:, :3, 3], dang], -1) / (2 * FD_STEP)

    _assert_fd(robot.jacobian_analytic(q, representation), _fd_joint(robot, q, diff),
               f"{name} analytic {representation} Jacobian")


@pytest.mark.parametrize("name", SERIAL)
def test_parameter_jacobian_equals_finite_differences(name):
    robot = framed(name)
    q = random_q(_doc(name), _rng(name, 4), 6)
    T = robot.fk(q)
    p0 = robot.param_values
    cols = []
    for k in range(robot.num_params):
        e = np.zeros(robot.num_params)
        e[k] = FD_STEP
        cols.append(_fd_twist(robot.with_params(p0 + e).fk(q), robot.with_params(p0 - e).fk(q),
                              T))
    Jfd = np.stack(cols, -1)
    _assert_fd(robot.param_jacobian(q), Jfd, f"{name} parameter Jacobian")
    names = [n for n in robot.param_names if n.startswith(("d[", "tool."))]
    idx = [robot.param_names.index(n) for n in names]
    _assert_fd(robot.param_jacobian(q, names), Jfd[:, :, idx], f"{name} named columns")


# --------------------------------------------------------------------------- forms and files
@pytest.mark.parametrize("name", STANDARD)
def test_standard_and_modified_dh_agree(name):
    robot = framed(name)
    mod = standard_to_modified(robot)
    assert mod.meta["convention"] == "modified_dh"
    assert mod.joint_names == robot.joint_names
    q = random_q(_doc(name), _rng(name, 5), 25)
    assert _max_err(mod.fk(q), robot.fk(q)) <= FK_TOL


def ets_document(robot) -> dict:
    """The robot as a ``convention: ets`` YAML document, built from its elementary transforms."""
    values = robot.params()
    chain = []
    for et in robot.ets:
        pname = robot.param_names[et.param] if et.param >= 0 else None
        if pname is not None and pname.startswith(("base.", "tool.")):
            continue
        row = {"transform": et.kind, "name": pname,
               "value": values[pname] if pname is not None else et.constant}
        if pname is not None:
            row["role"] = robot.param_roles[et.param]
        if et.joint >= 0:
            row["joint"] = robot.joints[et.joint].name
            row["scale"] = et.scale
        chain.append(row)
    joints = []
    for j in robot.joints:
        row = {"name": j.name, "type": j.kind}
        if math.isfinite(j.lower):
            row["limits"] = [j.lower, j.upper]
        joints.append(row)
    return {"name": robot.name, "units": {"length": "m", "angle": "rad"}, "convention": "ets",
            "base": {k: values[f"base.{k}"] for k in FRAME_KEYS},
            "tool": {k: values[f"tool.{k}"] for k in FRAME_KEYS},
            "joints": joints, "chain": chain}


def _assert_same_robot(a, b, q) -> None:
    assert b.param_names == a.param_names
    assert b.param_units == a.param_units
    assert b.param_roles == a.param_roles
    np.testing.assert_array_equal(b.param_values, a.param_values)
    assert b.joints == a.joints
    assert _max_err(b.fk(q), a.fk(q)) <= FK_TOL


@pytest.mark.parametrize("name", SERIAL)
def test_ets_form_agrees(name):
    robot = framed(name)
    text = yaml.safe_dump(ets_document(robot), sort_keys=False)
    chain_robot = robot_from_dict(yaml.safe_load(text), f"{name} (ets)")
    assert chain_robot.meta["convention"] == "ets"
    _assert_same_robot(robot, chain_robot, random_q(_doc(name), _rng(name, 6), 25))


@pytest.mark.parametrize("name", SERIAL)
def test_yaml_round_trip(name, tmp_path):
    q = random_q(_doc(name), _rng(name, 7), 25)
    for robot in (load_serial_robot(name), framed(name)):
        path = tmp_path / f"{name}.yaml"
        write_robot_yaml(robot, path)
        back = read_robot_yaml(path)
        _assert_same_robot(robot, back, q)
        assert back.name == robot.name
        for key in ("convention", "source", "description", "notes"):
            assert back.meta.get(key) == robot.meta.get(key)


# --------------------------------------------------------------------------- command line
def test_cli_lists_every_library_robot():
    result = CliRunner().invoke(app, ["robots"], env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    for name in library_names():
        assert name in result.output


@pytest.mark.parametrize("name", SERIAL)
def test_cli_show(name):
    result = CliRunner().invoke(app, ["show", name], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    robot = load_serial_robot(name)
    assert all(p in result.output for p in robot.param_names)
