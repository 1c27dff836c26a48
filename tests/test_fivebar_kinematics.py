"""Five-bar kinematics: round trips, closure, continuity, singularities, workspace."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError, UnreachableError
from kincal.parallel.files import load_fivebar
from kincal.parallel.fivebar import FiveBar
from kincal.parallel.workspace import plot_workspace, workspace

MODES = ("++", "+-", "-+", "--")
# Round trips away from singularities: the error is eps times the condition number
# (about 1 / measure <= 20) times the size (<= 5 m), far below 1e-12.
ROUND_TRIP_TOL = 1e-12
MIN_MEASURE = 0.05


def random_robot(rng: np.random.Generator) -> FiveBar:
    return FiveBar(
        l1=rng.uniform(0.5, 1.5),
        l2=rng.uniform(0.5, 1.5),
        l3=rng.uniform(1.0, 2.5),
        l4=rng.uniform(1.0, 2.5),
        base1_x=rng.uniform(-1.0, -0.2),
        base1_y=rng.uniform(-0.3, 0.3),
        base2_x=rng.uniform(0.2, 1.0),
        base2_y=rng.uniform(-0.3, 0.3),
        offset1=rng.uniform(-0.3, 0.3),
        offset2=rng.uniform(-0.3, 0.3),
    )


def well_conditioned(robot: FiveBar, q: np.ndarray, x: np.ndarray) -> np.ndarray:
    m = robot.singularity_measures(q, x)
    return (m["type1"].min(axis=1) > MIN_MEASURE) & (m["type2"] > MIN_MEASURE)


def angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi)


def test_ik_of_fk_returns_readings_in_all_modes() -> None:
    counts: dict[tuple[int, str], int] = {}
    for seed in range(4):
        rng = np.random.default_rng(seed)
        robot = random_robot(rng)
        q = rng.uniform(-np.pi, np.pi, (4000, 2))
        for assembly in (1, -1):
            x, ok = robot.fk_masked(q, assembly)
            keep = ok & well_conditioned(robot, np.where(ok[:, None], q, 0), np.nan_to_num(x))
            qk, xk = q[keep], x[keep]
            sigma, modes = robot.configuration_signs(qk, xk)
            assert np.all(sigma == assembly)
            for mode in MODES:
                sel = modes == mode
                counts[(assembly, mode)] = counts.get((assembly, mode), 0) + int(sel.sum())
                q_back = robot.ik(xk[sel], mode)
                assert np.max(angle_diff(q_back, qk[sel]), initial=0.0) < ROUND_TRIP_TOL
    assert len(counts) == 8 and min(counts.values()) >= 50, counts


def test_fk_of_ik_returns_point_in_all_modes() -> None:
    counts: dict[tuple[int, str], int] = {}
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        robot = random_robot(rng)
        x = rng.uniform(-3.5, 3.5, (6000, 2))
        for mode in MODES:
            q, ok = robot.ik_masked(x, mode)
            keep = ok & well_conditioned(robot, np.where(ok[:, None], q, 0), x)
            sigma, modes = robot.configuration_signs(q[keep], x[keep])
            assert np.all(modes == mode)
            for assembly in (1, -1):
                sel = sigma == assembly
                counts[(assembly, mode)] = counts.get((assembly, mode), 0) + int(sel.sum())
                x_back = robot.fk(q[keep][sel], assembly)
                assert np.max(np.abs(x_back - x[keep][sel]), initial=0.0) < ROUND_TRIP_TOL
    assert len(counts) == 8 and min(counts.values()) >= 50, counts


def test_fk_closes_the_loop_and_passive_angles_agree() -> None:
    rng = np.random.default_rng(7)
    robot = random_robot(rng)
    q = rng.uniform(-np.pi, np.pi, (500, 2))
    for assembly in (1, -1):
        x, ok = robot.fk_masked(q, assembly)
        j1, j2 = robot.elbows(q[ok])
        # independent closed form: the distal link lengths and the elbow positions
        b1 = np.array([robot.base1_x, robot.base1_y])
        beta1 = q[ok, 0] + robot.offset1
        assert np.allclose(j1, b1 + robot.l1 * np.c_[np.cos(beta1), np.sin(beta1)], atol=1e-14)
        assert np.allclose(np.linalg.norm(x[ok] - j1, axis=1), robot.l3, atol=1e-13)
        assert np.allclose(np.linalg.norm(x[ok] - j2, axis=1), robot.l4, atol=1e-13)
        b3, b4 = robot.passive_angles(q[ok], assembly=assembly).T
        assert np.allclose(j1 + robot.l3 * np.c_[np.cos(b3), np.sin(b3)], x[ok], atol=1e-13)
        assert np.allclose(j2 + robot.l4 * np.c_[np.cos(b4), np.sin(b4)], x[ok], atol=1e-13)
        # assembly sign: J3 left (+1) or right (-1) of J1 -> J2
        d, e = j2 - j1, x[ok] - j1
        assert np.all(np.sign(d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]) == assembly)


def test_single_configuration_shapes() -> None:
    robot = load_fivebar("fivebar_reference")
    q = np.array([0.6, 2.5])
    x = robot.fk(q)
    assert x.shape == (2,)
    assert robot.ik(x).shape == (2,)
    assert np.allclose(robot.ik(x), q, atol=1e-12)
    assert robot.passive_angles(q).shape == (2,)
    q_ik, passive = robot.ik_with_passive(x)
    assert np.allclose(q_ik, q, atol=1e-12)
    assert np.allclose(passive, robot.passive_angles(q), atol=1e-12)
    assert robot.singularity_measures(q)["type1"].shape == (2,)
    with pytest.raises(KincalError, match="shape"):
        robot.fk(np.zeros(3))


def test_thesis_robot_default_modes_match_its_layout() -> None:
    robot = load_fivebar("fivebar_reference")
    rng = np.random.default_rng(0)
    q = np.c_[rng.uniform(0.1, 1.4, 200), rng.uniform(1.7, 3.0, 200)]
    x = robot.fk(q)
    assert np.all(x[:, 1] > 0.0), "default assembly puts J3 above the bases"
    sigma, modes = robot.configuration_signs(q, x)
    assert set(modes) == {robot.working_mode}


def test_unreachable_raises_or_gives_nan_with_mask() -> None:
    robot = FiveBar(l1=1.0, l2=1.0, l3=1.0, l4=1.0, base1_x=-1.0, base2_x=1.0)
    # q = (pi, 0): elbows (-2, 0) and (2, 0), |J1J2| = 4 m > l3 + l4 = 2 m
    q = np.array([[1.5, 1.6], [np.pi, 0.0]])
    with pytest.raises(UnreachableError, match=r"configuration 1 .*\|J1J2\| = 4 m"):
        robot.fk(q)
    x, ok = robot.fk_masked(q)
    assert ok.tolist() == [True, False]
    assert np.all(np.isfinite(x[0])) and np.all(np.isnan(x[1]))
    assert np.array_equal(robot.fk(q, unreachable="nan"), x, equal_nan=True)
    points = np.array([[0.0, 1.5], [0.0, 9.0]])
    with pytest.raises(UnreachableError, match="cannot reach point 1"):
        robot.ik(points)
    q_nan = robot.ik(points, unreachable="nan")
    assert np.all(np.isfinite(q_nan[0])) and np.all(np.isnan(q_nan[1]))


def reference_continuous(robot: FiveBar, q: np.ndarray) -> np.ndarray:
    """Plain loop of the rule: default first, then nearest 2 x[k-1] - x[k-2] (x[0] for k=1)."""
    xp, xm = robot.fk(q, 1, "nan"), robot.fk(q, -1, "nan")
    out = np.empty_like(xp)
    sigma = robot.assembly
    out[0] = xp[0] if sigma > 0 else xm[0]
    for k in range(1, len(q)):
        ref = out[0] if k == 1 else 2 * out[k - 1] - out[k - 2]
        mine, other = (xp[k], xm[k]) if sigma > 0 else (xm[k], xp[k])
        if np.linalg.norm(other - ref) < np.linalg.norm(mine - ref):
            sigma, mine = -sigma, other
        out[k] = mine
    return out


def test_continuous_assembly_crosses_a_type2_singularity() -> None:
    robot = FiveBar(l1=1.0, l2=1.0, l3=1.5, l4=1.5, base1_x=-0.5, base2_x=0.5)
    # J3 driven along a straight line through the Type-2 curve of working mode -+
    s = np.linspace(0.5, 1.4, 301)
    x_path = np.c_[0.05 + 0.1 * s, s]
    q = robot.ik(x_path, "-+")
    sigma, _ = robot.configuration_signs(q, x_path)
    assert sigma[0] != sigma[-1], "the path crosses the Type-2 singularity"
    start = robot.with_defaults(assembly=int(sigma[0]))
    x_cont = start.fk(q, "continuous")
    assert np.max(np.abs(x_cont - x_path)) < 1e-9
    assert np.array_equal(x_cont, reference_continuous(start, q))
    # a fixed assembly mode jumps to the mirror image after the crossing
    assert np.max(np.abs(start.fk(q) - x_path)) > 0.1


def test_continuous_assembly_matches_the_loop_on_a_random_walk() -> None:
    robot = load_fivebar("fivebar_reference")
    rng = np.random.default_rng(5)
    q = np.array([0.7, 2.3]) + np.cumsum(rng.normal(0.0, 0.05, (2000, 2)), axis=0)
    x_cont = robot.fk(q, "continuous", unreachable="nan")
    assert np.array_equal(x_cont, reference_continuous(robot, q), equal_nan=True)
    # without a singular crossing a smooth path stays in the default assembly
    t = np.linspace(0.0, 1.0, 200)
    q_smooth = np.c_[0.3 + 0.5 * t, 2.0 + 0.5 * t]
    assert np.array_equal(robot.fk(q_smooth, "continuous"), robot.fk(q_smooth))


def test_singularity_measures_at_constructed_singular_configurations() -> None:
    robot = load_fivebar("fivebar_reference")
    # Type 1: arm 1 stretched, J3 on the circle of radius l1 + l3 about B1
    b1 = np.array([robot.base1_x, robot.base1_y])
    x1 = b1 + (robot.l1 + robot.l3) * np.array([np.cos(1.9), np.sin(1.9)])
    q1 = robot.ik(x1, "-+")
    m1 = robot.singularity_measures(q1, x1)
    assert m1["type1"][0] < 1e-7 and m1["type2"] > 0.1
    assert robot.singular(q1, x1)["type1"] and not robot.singular(q1, x1)["type2"]
    # Type 2: B1 = (-0.5, -1), B2 = (0.5, -1), beta = (pi/2, pi/2): J1 = (-0.5, 0),
    # J2 = (0.5, 0); l3 = 2, l4 = 1 put J3 = (1.5, 0) on the line J1J2 (folded)
    folded = FiveBar(l1=1, l2=1, l3=2, l4=1, base1_x=-0.5, base1_y=-1, base2_x=0.5, base2_y=-1)
    q2 = np.array([np.pi / 2, np.pi / 2])
    x2 = np.array([1.5, 0.0])
    m2 = folded.singularity_measures(q2, x2)
    assert m2["type2"] < 1e-15 and m2["type1"].min() > 0.5
    assert np.allclose(folded.fk(q2, 1), x2, atol=1e-7)
    assert np.allclose(folded.fk(q2, -1), x2, atol=1e-7)
    # the measures are |sin| of the link angles, computed independently via atan2
    q = np.array([0.6, 2.5])
    b3, b4 = robot.passive_angles(q)
    m = robot.singularity_measures(q)
    beta = q + np.array([robot.offset1, robot.offset2])
    assert np.allclose(m["type1"], np.abs(np.sin([b3 - beta[0], b4 - beta[1]])), atol=1e-14)
    assert m["type2"] == pytest.approx(abs(np.sin(b4 - b3)), abs=1e-14)


def test_with_params_is_a_new_value() -> None:
    robot = load_fivebar("fivebar_reference")
    other = robot.with_params({"l1": 1.86, "offset2": 0.01})
    assert robot.l1 == 2.0 and other.l1 == 1.86 and other.offset2 == 0.01
    assert np.array_equal(robot.with_params(other.param_values).param_values, other.param_values)
    assert [row[0] for row in robot.parameter_table()] == list(robot.param_names)
    assert robot.param_units[-1] == "rad"
    with pytest.raises(KincalError, match="unknown five-bar parameter"):
        robot.with_params({"l5": 1.0})
    with pytest.raises(AttributeError):
        robot.l1 = 3.0  # type: ignore[misc]


def test_workspace_area_and_membership() -> None:
    # bases 1e-9 m apart: the region is one annulus, area 4 pi l1 l3
    robot = FiveBar(l1=1.0, l2=1.0, l3=2.0, l4=2.0, base1_x=0.0, base2_x=1e-9)
    ws = workspace(robot, "+-", resolution=600)
    assert ws.area == pytest.approx(4 * np.pi * 1.0 * 2.0, rel=0.01)
    thesis = load_fivebar("fivebar_reference")
    ws = workspace(thesis, resolution=120)
    gx, gy = np.meshgrid(ws.xs, ws.ys)
    pts = np.c_[gx.ravel(), gy.ravel()]
    q, ok = thesis.ik_masked(pts)
    inside = ws.reachable.ravel()
    assert np.all(ok[inside])
    lim = np.array(thesis.limits)
    assert np.all((q[inside] >= lim[:, 0] - 1e-12) & (q[inside] <= lim[:, 1] + 1e-12))


def test_workspace_plot_written(tmp_path) -> None:
    path = plot_workspace(load_fivebar("fivebar"), tmp_path / "ws.png", resolution=60)
    assert path.is_file() and path.stat().st_size > 1000
