"""The elementary-transform chain against independent computations: explicit 4x4
products for forward kinematics and central finite differences for every Jacobian."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kincal.errors import KincalError
from kincal.robots.chain import ChainBuilder, Robot

RNG = np.random.default_rng(11)
H = 1e-6  # finite-difference step


# --------------------------------------------------------------------------- reference
def _elementary(kind: str, v: float) -> np.ndarray:
    """4x4 of one elementary transform, written out by hand."""
    T = np.eye(4)
    c, s = np.cos(v), np.sin(v)
    if kind == "Rx":
        T[1:3, 1:3] = [[c, -s], [s, c]]
    elif kind == "Ry":
        T[0, 0], T[0, 2], T[2, 0], T[2, 2] = c, s, -s, c
    elif kind == "Rz":
        T[0:2, 0:2] = [[c, -s], [s, c]]
    else:
        T["xyz".index(kind[1]), 3] = v
    return T


def reference_fk(robot: Robot, q: np.ndarray, upto: int | None = None) -> np.ndarray:
    """Product of the elementary transforms (first ``upto``) for one configuration."""
    T = np.eye(4)
    for et in robot.ets[:upto]:
        v = robot.param_values[et.param] if et.param >= 0 else et.constant
        if et.joint >= 0:
            v = v + et.scale * q[et.joint]
        T = T @ _elementary(et.kind, v)
    return T


def _vee(S: np.ndarray) -> np.ndarray:
    return np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0],
                     S[..., 1, 0] - S[..., 0, 1]], -1) / 2.0


def fd_twist(fk_plus: np.ndarray, fk_minus: np.ndarray, h: float) -> np.ndarray:
    """Central difference of a pose: [dp/dx; omega] with [omega]x = dR/dx R^T."""
    dp = (fk_plus[..., :3, 3] - fk_minus[..., :3, 3]) / (2 * h)
    R = (fk_plus[..., :3, :3] + fk_minus[..., :3, :3]) / 2
    dR = (fk_plus[..., :3, :3] - fk_minus[..., :3, :3]) / (2 * h)
    return np.concatenate([dp, _vee(dR @ np.swapaxes(R, -1, -2))], -1)


def fd_joint_jacobian(robot: Robot, Q: np.ndarray) -> np.ndarray:
    out = np.zeros((Q.shape[0], 6, robot.n))
    for k in range(robot.n):
        dq = np.zeros(robot.n)
        dq[k] = H
        out[:, :, k] = fd_twist(robot.fk(Q + dq), robot.fk(Q - dq), H)
    return out


def fd_param_jacobian(robot: Robot, Q: np.ndarray) -> np.ndarray:
    p0 = robot.param_values
    out = np.zeros((Q.shape[0], 6, robot.num_params))
    for k in range(robot.num_params):
        dp = np.zeros_like(p0)
        dp[k] = H
        out[:, :, k] = fd_twist(robot.with_params(p0 + dp).fk(Q),
                                robot.with_params(p0 - dp).fk(Q), H)
    return out


def assert_fd_close(analytic: np.ndarray, numeric: np.ndarray) -> None:
    """Relative 1e-6 (entries of order 1), absolute 1e-8 for entries near zero."""
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-8)


# --------------------------------------------------------------------------- robots
def every_kind_robot() -> Robot:
    """All six elementary kinds, revolute and prismatic joints, negative scales, fixed
    constants (name=None) carrying and not carrying joints, base and tool frames."""
    b = ChainBuilder("every_kind")
    b.frame("base", [0.1, -0.2, 0.3, 0.2, -0.4, 0.6])
    j1 = b.joint("j1", "revolute", -3, 3)
    j2 = b.joint("j2", "revolute")
    j3 = b.joint("j3", "prismatic", -0.5, 0.5)
    j4 = b.joint("j4", "revolute")
    j5 = b.joint("j5", "prismatic")
    j6 = b.joint("j6", "revolute")
    j7 = b.joint("j7", "prismatic")
    j8 = b.joint("j8", "revolute")
    b.transform("Rz", "theta_offset[1]", 0.1, role="offset", joint=j1)
    b.transform("Tz", "d[1]", 0.35)
    b.transform("Rx", None, np.pi / 2)                         # fixed constant
    b.transform("Ry", "off[2]", -0.2, role="offset", joint=j2, scale=-1.0)
    b.transform("Tx", "a[2]", 0.4)
    b.transform("Ty", "b[2]", -0.05)
    b.transform("Tx", "s[3]", 0.02, role="offset", joint=j3)
    b.transform("Ry", "beta[3]", 0.03, role="angle")
    b.transform("Rx", "off[4]", 0.3, role="offset", joint=j4)
    b.transform("Ty", "s[5]", 0.0, role="offset", joint=j5, scale=-1.0)
    b.transform("Tz", None, 0.07)                              # fixed constant
    b.transform("Rz", None, 0.25, joint=j6)                    # fixed constant with a joint
    b.transform("Tz", None, 0.0, joint=j7, scale=-1.0)         # prismatic fixed, negative
    b.transform("Rx", "alpha[7]", -np.pi / 2)
    b.transform("Rx", "off[8]", 0.0, role="offset", joint=j8, scale=-1.0)
    b.transform("Ty", "e[8]", 0.011)
    b.frame("tool", [0.01, 0.02, 0.15, -0.3, 0.25, 0.7])
    return b.build(meta={"source": "test"})


def bare_robot() -> Robot:
    """No base or tool frame; a joint first and last; two joints in a row."""
    b = ChainBuilder("bare")
    j1, j2, j3 = (b.joint(f"q{i}", "revolute") for i in (1, 2, 3))
    b.transform("Rx", None, 0.0, joint=j1)
    b.transform("Rz", None, 0.0, joint=j2, scale=-1.0)
    b.transform("Tx", "a", 0.3)
    b.transform("Ry", "t3", 0.2, role="offset", joint=j3)
    return b.build()


ROBOTS = {"every_kind": every_kind_robot, "bare": bare_robot}


def configurations(robot: Robot, N: int) -> np.ndarray:
    return RNG.uniform(-2.0, 2.0, (N, robot.n))


# --------------------------------------------------------------------------- fk
@pytest.mark.parametrize("make", ROBOTS.values(), ids=ROBOTS.keys())
def test_fk_equals_explicit_product(make):
    robot = make()
    Q = configurations(robot, 25)
    T = robot.fk(Q)
    assert T.shape == (25, 4, 4)
    for q, Tq in zip(Q, T, strict=True):
        np.testing.assert_allclose(Tq, reference_fk(robot, q), atol=1e-12)
    np.testing.assert_array_equal(T[:, 3], np.tile([0.0, 0, 0, 1], (25, 1)))


def test_fk_single_and_batch_shapes():
    robot = every_kind_robot()
    Q = configurations(robot, 4)
    T1 = robot.fk(Q[1])
    assert T1.shape == (4, 4)
    np.testing.assert_allclose(T1, robot.fk(Q)[1], atol=1e-15)
    np.testing.assert_allclose(robot.fk(Q[1:2])[0], T1, atol=1e-15)
    assert robot.fk(Q[1].tolist()).shape == (4, 4)
    assert robot.jacobian(Q[1]).shape == (6, robot.n)
    assert robot.jacobian(Q).shape == (4, 6, robot.n)
    assert robot.param_jacobian(Q[1]).shape == (6, robot.num_params)
    T, J, Jp = robot.fk_with_jacobians(Q[1])
    assert T.shape == (1, 4, 4) and J.shape == (1, 6, robot.n)
    assert Jp.shape == (1, 6, robot.num_params)


@pytest.mark.parametrize("bad", [np.zeros(3), np.zeros((5, 9)), np.zeros((2, 3, 8))])
def test_fk_wrong_shape_is_a_kincal_error(bad):
    with pytest.raises(KincalError, match="8 joints"):
        every_kind_robot().fk(bad)


def test_frames_last_equals_fk_and_each_joint_frame_is_the_partial_product():
    robot = every_kind_robot()
    Q = configurations(robot, 5)
    F = robot.frames(Q)
    assert F.shape == (5, robot.n + 2, 4, 4)
    np.testing.assert_allclose(F[:, -1], robot.fk(Q), atol=1e-12)
    carriers = [k for k, et in enumerate(robot.ets) if et.joint >= 0]
    for i, q in enumerate(Q):
        np.testing.assert_allclose(F[i, 0], reference_fk(robot, q, carriers[0]), atol=1e-12)
        for slot, k in enumerate(carriers, start=1):
            np.testing.assert_allclose(F[i, slot], reference_fk(robot, q, k + 1), atol=1e-12)
    np.testing.assert_allclose(robot.frames(Q[2]), F[2], atol=1e-15)


# --------------------------------------------------------------------------- jacobians
@pytest.mark.parametrize("make", ROBOTS.values(), ids=ROBOTS.keys())
def test_geometric_jacobian_base_frame_equals_finite_differences(make):
    robot = make()
    Q = configurations(robot, 20)
    assert_fd_close(robot.jacobian(Q), fd_joint_jacobian(robot, Q))
    assert_fd_close(robot.jacobian(Q, "base"), fd_joint_jacobian(robot, Q))


def test_geometric_jacobian_tool_frame():
    robot = every_kind_robot()
    Q = configurations(robot, 20)
    J0 = fd_joint_jacobian(robot, Q)
    R = robot.fk(Q)[:, :3, :3]
    Rt = np.swapaxes(R, 1, 2)
    want = np.concatenate([Rt @ J0[:, :3], Rt @ J0[:, 3:]], 1)
    assert_fd_close(robot.jacobian(Q, frame="tool"), want)
    # the tool-frame angular velocity is R^T omega: check one column by hand too
    q = Q[0]
    dq = np.zeros(robot.n)
    dq[3] = H
    Tp, Tm = robot.fk(q + dq), robot.fk(q - dq)
    dT = (Tp - Tm) / (2 * H)
    body = np.linalg.inv(robot.fk(q)) @ dT                     # [omega_e]x, v_e
    assert_fd_close(robot.jacobian(q, "tool")[:, 3],
                    np.concatenate([body[:3, 3], _vee(body[:3, :3])]))
    with pytest.raises(KincalError, match="frame"):
        robot.jacobian(q, frame="world")  # type: ignore[arg-type]


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


@pytest.mark.parametrize("rep", ["zyz", "rpy"])
def test_analytic_jacobian_equals_finite_differences_of_the_angles(rep):
    from kincal.spatial import matrix_to_angles

    robot = every_kind_robot()
    Q = configurations(robot, 30)
    ang = matrix_to_angles(robot.fk(Q)[:, :3, :3], rep)
    mid = ang[:, 1] if rep == "zyz" else np.abs(ang[:, 1]) - np.pi / 2
    Q = Q[np.abs(np.sin(mid)) > 0.1] if rep == "zyz" else Q[np.abs(mid) > 0.1]
    assert len(Q) >= 10
    JA = robot.jacobian_analytic(Q, rep)
    want = np.zeros_like(JA)
    for k in range(robot.n):
        dq = np.zeros(robot.n)
        dq[k] = H
        Tp, Tm = robot.fk(Q + dq), robot.fk(Q - dq)
        want[:, :3, k] = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * H)
        want[:, 3:, k] = _wrap(matrix_to_angles(Tp[:, :3, :3], rep)
                               - matrix_to_angles(Tm[:, :3, :3], rep)) / (2 * H)
    assert_fd_close(JA, want)
    np.testing.assert_allclose(robot.jacobian_analytic(Q[0], rep), JA[0], atol=1e-14)


def test_analytic_jacobian_raises_at_a_representation_singularity():
    b = ChainBuilder("rz_rz")
    j1, j2 = b.joint("q1", "revolute"), b.joint("q2", "revolute")
    b.transform("Rz", None, 0.0, joint=j1)
    b.transform("Tx", "a", 0.5)
    b.transform("Rz", None, 0.0, joint=j2)
    planar = b.build()                          # R = Rz: ZYZ theta = 0 everywhere
    with pytest.raises(KincalError, match="ZYZ.*singular"):
        planar.jacobian_analytic([0.3, 0.4], "zyz")
    assert np.isfinite(planar.jacobian_analytic([0.3, 0.4], "rpy")).all()

    b = ChainBuilder("ry")
    j = b.joint("q1", "revolute")
    b.transform("Ry", None, 0.0, joint=j)
    pitch = b.build()
    with pytest.raises(KincalError, match="RPY.*singular"):
        pitch.jacobian_analytic(np.array([[0.1], [np.pi / 2]]), "rpy")
    with pytest.raises(KincalError, match="unknown orientation"):
        pitch.jacobian_analytic([0.1], "xyz")  # type: ignore[arg-type]


@pytest.mark.parametrize("make", ROBOTS.values(), ids=ROBOTS.keys())
def test_parameter_jacobian_equals_finite_differences(make):
    robot = make()
    Q = configurations(robot, 12)
    Jp = robot.param_jacobian(Q)
    assert Jp.shape == (12, 6, robot.num_params)
    assert_fd_close(Jp, fd_param_jacobian(robot, Q))
    T, J, Jp2 = robot.fk_with_jacobians(Q)
    np.testing.assert_allclose(T, robot.fk(Q), atol=1e-15)
    np.testing.assert_allclose(J, robot.jacobian(Q), atol=1e-15)
    np.testing.assert_allclose(Jp2, Jp, atol=1e-15)


def test_parameter_jacobian_subset_follows_the_given_order():
    robot = every_kind_robot()
    Q = configurations(robot, 3)
    names = ["tool.rz", "a[2]", "base.x", "off[8]"]
    sub = robot.param_jacobian(Q, names)
    full = robot.param_jacobian(Q)
    for c, name in enumerate(names):
        np.testing.assert_array_equal(sub[:, :, c], full[:, :, robot.param_index(name)])
    # a translation parameter moves the tool along a unit axis and does not rotate it
    col = full[:, :, robot.param_index("base.x")]
    np.testing.assert_allclose(col, np.tile([1.0, 0, 0, 0, 0, 0], (3, 1)), atol=1e-15)


def test_joint_carried_by_a_parameter_has_equal_joint_and_parameter_columns():
    robot = every_kind_robot()
    Q = configurations(robot, 4)
    J = robot.jacobian(Q)
    Jp = robot.param_jacobian(Q)
    # joint j2 has scale -1, j1 scale +1
    np.testing.assert_allclose(J[:, :, 0], Jp[:, :, robot.param_index("theta_offset[1]")],
                               atol=1e-15)
    np.testing.assert_allclose(J[:, :, 1], -Jp[:, :, robot.param_index("off[2]")], atol=1e-15)


# --------------------------------------------------------------------------- with_params
def test_with_params_by_vector_and_by_dict():
    robot = every_kind_robot()
    old = robot.param_values.copy()
    q = configurations(robot, 1)[0]
    T_old = robot.fk(q)
    new_values = old + 0.01
    r2 = robot.with_params(new_values)
    assert r2 is not robot and isinstance(r2, Robot)
    np.testing.assert_array_equal(r2.param_values, new_values)
    np.testing.assert_array_equal(robot.param_values, old)
    np.testing.assert_allclose(robot.fk(q), T_old, atol=0)
    np.testing.assert_allclose(r2.fk(q), reference_fk(r2, q), atol=1e-12)

    r3 = robot.with_params({"a[2]": 0.5, "tool.z": -0.1})
    assert r3.params()["a[2]"] == 0.5 and r3.params()["tool.z"] == -0.1
    changed = np.flatnonzero(r3.param_values != old)
    assert sorted(robot.param_names[i] for i in changed) == ["a[2]", "tool.z"]
    np.testing.assert_array_equal(robot.param_values, old)
    assert robot.params()["a[2]"] == 0.4
    with pytest.raises(ValueError):
        robot.param_values[0] = 1.0                    # read-only
    with pytest.raises(KincalError, match=f"{robot.num_params} parameters"):
        robot.with_params(old[:-1])


def test_unknown_parameter_suggests_close_matches():
    robot = every_kind_robot()
    with pytest.raises(KincalError, match=r"no parameter 'tool\.zz'.*did you mean.*tool\.z"):
        robot.with_params({"tool.zz": 1.0})
    with pytest.raises(KincalError, match=r"did you mean.*theta_offset\[1\]"):
        robot.param_index("theta_ofset[1]")
    with pytest.raises(KincalError) as exc:
        robot.param_jacobian(np.zeros(robot.n), ["nothing_like_it_at_all"])
    assert "did you mean" not in str(exc.value)


def test_duplicate_parameter_name_is_refused():
    b = ChainBuilder("dup")
    b.transform("Tx", "a", 0.1)
    with pytest.raises(KincalError, match="'a' defined twice"):
        b.transform("Ty", "a", 0.2)


# --------------------------------------------------------------------------- random chains
KIND = st.sampled_from(["Rx", "Ry", "Rz", "Tx", "Ty", "Tz"])
STEP = st.tuples(KIND, st.floats(-2, 2), st.booleans(), st.booleans(), st.booleans())


@st.composite
def random_robots(draw):
    steps = draw(st.lists(STEP, min_size=1, max_size=14))
    b = ChainBuilder("random")
    if draw(st.booleans()):
        b.frame("base", draw(st.lists(st.floats(-2, 2), min_size=6, max_size=6)))
    for i, (kind, value, named, is_joint, negative) in enumerate(steps):
        j = -1
        if is_joint:
            j = b.joint(f"j{i}", "revolute" if kind[0] == "R" else "prismatic")
        b.transform(kind, f"p{i}" if named else None, value, joint=j,
                    scale=-1.0 if negative else 1.0)
    if draw(st.booleans()):
        b.frame("tool", draw(st.lists(st.floats(-2, 2), min_size=6, max_size=6)))
    return b.build()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(robot=random_robots(), seed=st.integers(0, 2**32 - 1))
def test_random_chains_fk_and_jacobians(robot, seed):
    Q = np.random.default_rng(seed).uniform(-2, 2, (3, robot.n))
    T, J, Jp = robot.fk_with_jacobians(Q)
    for q, Tq in zip(Q, T, strict=True):
        np.testing.assert_allclose(Tq, reference_fk(robot, q), atol=1e-12)
    np.testing.assert_allclose(robot.fk(Q), T, atol=1e-15)
    if robot.n:
        np.testing.assert_allclose(J, fd_joint_jacobian(robot, Q), rtol=1e-6, atol=1e-7)
    if robot.num_params:
        np.testing.assert_allclose(Jp, fd_param_jacobian(robot, Q), rtol=1e-6, atol=1e-7)


# --------------------------------------------------------------------------- batching
def test_large_batches_equal_single_configurations():
    """Batches are evaluated in blocks: the result must not depend on the block split."""
    robot = every_kind_robot()
    Q = np.random.default_rng(2).uniform(-2, 2, (5003, robot.n))
    T, J, Jp = robot.fk_with_jacobians(Q)
    np.testing.assert_array_equal(robot.fk(Q), T)
    for i in [0, 1, 511, 512, 513, 2047, 2048, 4095, 4096, 4097, 5002]:
        np.testing.assert_allclose(T[i], reference_fk(robot, Q[i]), atol=1e-12)
        np.testing.assert_allclose(J[i], robot.jacobian(Q[i]), atol=1e-14)
        np.testing.assert_allclose(Jp[i], robot.param_jacobian(Q[i]), atol=1e-14)
    assert robot.fk(np.zeros((0, robot.n))).shape == (0, 4, 4)
    assert robot.jacobian(np.zeros((0, robot.n))).shape == (0, 6, robot.n)


def test_joints_and_parameters_out_of_chain_order():
    """Joint j2 comes first in the chain; parameters are numbered against the chain, one
    is shared by two transforms and one is used by none."""
    from kincal.robots.chain import ElementaryTransform as E
    from kincal.robots.chain import Joint

    ets = (E("Tz", 3), E("Ry", 0, joint=1, scale=-1.0), E("Tx", 2), E("Rx", -1, 0.3),
           E("Rz", 1, joint=0), E("Tx", 2), E("Tz", -1, 0.0, joint=2, scale=-1.0), E("Ry", 4))
    robot = Robot("shuffled", ets, (Joint("a", "revolute"), Joint("b", "revolute"),
                                    Joint("c", "prismatic")),
                  ("p0", "p1", "len", "h", "tilt", "unused"),
                  np.array([0.2, -0.1, 0.3, 0.4, 0.05, 1.0]), ("rad", "rad", "m", "m", "rad", "m"),
                  ("offset", "offset", "length", "length", "angle", "length"))
    Q = configurations(robot, 8)
    for q, Tq in zip(Q, robot.fk(Q), strict=True):
        np.testing.assert_allclose(Tq, reference_fk(robot, q), atol=1e-12)
    assert_fd_close(robot.jacobian(Q), fd_joint_jacobian(robot, Q))
    Jp = robot.param_jacobian(Q)
    assert_fd_close(Jp, fd_param_jacobian(robot, Q))
    np.testing.assert_array_equal(Jp[:, :, robot.param_index("unused")], 0.0)


def test_robots_pickle_after_evaluation():
    import pickle

    robot = every_kind_robot()
    Q = configurations(robot, 3)
    T = robot.fk(Q)                                      # builds the evaluation plan
    back = pickle.loads(pickle.dumps(robot))
    np.testing.assert_array_equal(back.fk(Q), T)
    np.testing.assert_array_equal(back.param_jacobian(Q), robot.param_jacobian(Q))


def test_threads_evaluating_one_robot_agree():
    """Working arrays are per thread: concurrent calls must not mix their blocks."""
    from concurrent.futures import ThreadPoolExecutor

    robot = every_kind_robot()
    batches = [np.random.default_rng(s).uniform(-2, 2, (3000, robot.n)) for s in range(8)]
    want = [robot.fk_with_jacobians(Q) for Q in batches]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(robot.fk_with_jacobians, batches))
    for w, g in zip(want, got, strict=True):
        for a, b in zip(w, g, strict=True):
            np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- tool points
def _points_ref(T: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``T m_k`` for frames T (N, 4, 4) and points m (K, 3): (K, 3, N)."""
    return np.einsum("nij,kj->kin", T[:, :3, :3], m) + T[:, :3, 3].T[None]


def _points_fd(robot: Robot, Q: np.ndarray, m: np.ndarray, H: np.ndarray,
               columns: list[int], h: float = 1e-6) -> np.ndarray:
    """Central differences of ``y = H T(q) m`` with respect to the parameters ``columns``
    from the reference product: (C, K, 3, N)."""
    out = np.empty((len(columns), len(m), 3, len(Q)))
    for j, c in enumerate(columns):
        ys = []
        for sgn in (1.0, -1.0):
            v = robot.param_values.copy()
            v[c] += sgn * h
            r = robot.with_params(v)
            T = H @ np.array([reference_fk(r, q) for q in Q])
            ys.append(_points_ref(T, m))
        out[j] = (ys[0] - ys[1]) / (2 * h)
    return out


@pytest.mark.parametrize("make", [every_kind_robot, bare_robot], ids=["every_kind", "bare"])
@pytest.mark.parametrize("K", [1, 3])
def test_point_jacobian_equals_finite_differences(make, K):
    """Points on the tool seen from a frame H in front of the chain, and their parameter
    columns (all, a subset in another order, none) against central differences of the
    explicit product; the rotation is that of H T."""
    robot = make()
    Q = configurations(robot, 9)
    m = np.array([[0.02, -0.03, 0.07], [-0.05, 0.01, 0.1], [0.0, 0.06, 0.02]])[:K]
    H = np.linalg.inv(_elementary("Tx", 0.8) @ _elementary("Ty", -0.4) @ _elementary("Rz", 0.3)
                      @ _elementary("Ry", -0.2) @ _elementary("Rx", 0.1))
    T = H @ np.array([reference_fk(robot, q) for q in Q])
    every = list(range(robot.num_params))
    for cols in (every, every[::-3], []):
        Y, D, Rot = robot.point_jacobian(Q, m, H, cols, rotation=True)
        assert Y.shape == (K, 3, 9) and D.shape == (len(cols), K, 3, 9)
        np.testing.assert_allclose(Y, _points_ref(T, m), atol=1e-12)
        np.testing.assert_allclose(Rot, T[:, :3, :3].transpose(2, 1, 0), atol=1e-12)
        if cols:
            np.testing.assert_allclose(D, _points_fd(robot, Q, m, H, cols), rtol=1e-6, atol=1e-8)
    # the same as the 6-row parameter Jacobian moved to the point, no frame in front
    Y, D, _ = robot.point_jacobian(Q, m[:1])
    Jp = robot.param_jacobian(Q)
    arm = Y[0].T - robot.fk(Q)[:, :3, 3]
    ref = Jp[:, :3] + np.cross(Jp[:, 3:].transpose(0, 2, 1), arm[:, None, :]).transpose(0, 2, 1)
    np.testing.assert_allclose(D[:, 0].transpose(2, 1, 0), ref, atol=1e-13)


def test_point_jacobian_into_given_arrays():
    """``out=`` arrays (e.g. reused working memory holding old values) receive exactly the
    fresh results, over several blocks and a column subset; wrong shapes are refused."""
    robot = every_kind_robot()
    Q = np.random.default_rng(4).uniform(-2, 2, (9000, robot.n))
    m = np.array([[0.02, -0.03, 0.07], [-0.05, 0.01, 0.1]])
    cols = [5, 0, 9]
    ref = robot.point_jacobian(Q, m, None, cols, rotation=True)
    out = (np.full((2, 3, 9000), np.nan), np.full((3, 2, 3, 9000), np.nan),
           np.full((3, 3, 9000), np.nan))
    got = robot.point_jacobian(Q, m, None, cols, rotation=True, out=out)
    for g, o, r in zip(got, out, ref, strict=True):
        assert g is o
        np.testing.assert_array_equal(g, r)
    with pytest.raises(ValueError, match="out"):
        robot.point_jacobian(Q, m, None, cols, rotation=False, out=out)


def test_point_jacobian_blocks_and_shared_parameters():
    """Several blocks of configurations give the values of one; a parameter used by two
    transforms and one used by none (out of chain order) get summed and zero columns."""
    robot = every_kind_robot()
    Q = np.random.default_rng(3).uniform(-2, 2, (9000, robot.n))
    m = np.array([[0.02, -0.03, 0.07]])
    Y, D, _ = robot.point_jacobian(Q, m, columns=[5, 0, 9])
    for i in (0, 4095, 4096, 8999):
        Yi, Di, _ = robot.point_jacobian(Q[i:i + 1], m, columns=[5, 0, 9])
        np.testing.assert_allclose(Y[..., i], Yi[..., 0], atol=1e-15)
        np.testing.assert_allclose(D[..., i], Di[..., 0], atol=1e-14)
    from kincal.robots.chain import ElementaryTransform as E
    from kincal.robots.chain import Joint

    ets = (E("Tz", 3), E("Ry", 0, joint=1, scale=-1.0), E("Tx", 2), E("Rx", -1, 0.3),
           E("Rz", 1, joint=0), E("Tx", 2), E("Ry", 4))
    shuffled = Robot("shuffled", ets, (Joint("a", "revolute"), Joint("b", "revolute")),
                     ("p0", "p1", "len", "h", "tilt", "unused"),
                     np.array([0.2, -0.1, 0.3, 0.4, 0.05, 1.0]),
                     ("rad", "rad", "m", "m", "rad", "m"),
                     ("offset", "offset", "length", "length", "angle", "length"))
    Qs = configurations(shuffled, 6)
    _, D, _ = shuffled.point_jacobian(Qs, m, columns=[5, 2, 0, 4])
    np.testing.assert_allclose(D, _points_fd(shuffled, Qs, m, np.eye(4), [5, 2, 0, 4]),
                               rtol=1e-6, atol=1e-8)
    np.testing.assert_array_equal(D[0], 0.0)
