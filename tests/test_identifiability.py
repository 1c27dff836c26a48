"""Identifiability: the counts theory predicts, by name and with reasons."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kincal.identify.identifiability import analyze, default_priority
from kincal.measure.base import stack
from kincal.measure.instruments.pose import simulate_poses
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import random_configurations
from kincal.robots.dh import dh_links, from_dh
from kincal.robots.files import load_serial_robot

TOOL = [0.05, 0.03, 0.1, 0, 0, 0]      # tool point away from the wrist centre


def puma(hayati: bool = False):
    links = dh_links(load_serial_robot("puma560"))
    if hayati:
        links[1] = replace(links[1], beta=0.0)       # Hayati's beta on the parallel pair 2-3
    return from_dh(links, name="puma_hayati" if hayati else "puma560", tool=TOOL)


def robot_jacobian(robot, pose: bool, n: int = 40, seed: int = 0):
    """Whitened J over the robot's own 36 (37) parameters; instrument frame held known."""
    rng = np.random.default_rng(seed)
    q = random_configurations(robot, n, rng)
    blk = simulate_poses(robot, q, rng, 0, 0) if pose else simulate_positions(robot, q, rng, 0)
    prob, theta = stack(robot, [blk])
    theta[robot.num_params:] = 0.0          # instrument at the origin, marker at tool origin
    _, J = prob.residuals_and_jacobian(theta)
    P = robot.num_params
    return J[:, :P], prob.names[:P], prob.roles[:P]


@pytest.mark.parametrize("hayati,pose,expected", [
    (False, True, 29), (False, False, 26), (True, True, 30), (True, False, 27)])
def test_puma_counts_match_theory(hayati, pose, expected):
    robot = puma(hayati)
    J, names, roles = robot_jacobian(robot, pose)
    rep = analyze(J, names, roles=roles)
    print(f"\nPUMA 560 {'Hayati' if hayati else 'std DH'} {'pose' if pose else 'position'}: "
          f"{rep.rank} identifiable of {len(names)}, cond_scaled {rep.cond_scaled:.3g}")
    assert rep.rank == expected == len(rep.identifiable)
    assert len(rep.identifiable) + len(rep.unobservable) + len(rep.dependent) == len(names)
    # the parallel pair 2-3: d[2] and d[3] slide along parallel axes (only their sum is
    # seen) in both conventions; Hayati's beta adds the tilt standard DH cannot express
    assert rep.dependent["d[3]"] == ["d[2]"]
    assert rep.combinations["d[3]"]["d[2]"] == pytest.approx(1.0, abs=1e-9)
    if hayati:
        assert "beta[2]" in rep.identifiable
    if not pose:
        assert set(rep.unobservable) == {"tool.rz", "tool.ry", "tool.rx"}
        assert all("does not affect" in s for s in rep.describe() if s.startswith("tool.r"))
    # base frame duplicates the first joint: base.z ~ d[1], base.rz ~ theta_offset[1]
    assert rep.dependent["base.z"] == ["d[1]"]
    assert rep.dependent["base.rz"] == ["theta_offset[1]"]
    sentences = rep.describe()
    assert len(sentences) == len(names) - rep.rank
    assert any(s.startswith("base.rz cannot be told apart from theta_offset[1]")
               for s in sentences)


def test_instrument_frame_takes_priority_over_robot_base():
    robot = puma()
    rng = np.random.default_rng(1)
    blk = simulate_positions(robot, random_configurations(robot, 30, rng), rng, 0,
                             [1, 0.5, 0.2, 0.1, 0.2, 0.3], [0.01, 0.02, 0.03])
    prob, theta = stack(robot, [blk])
    _, J = prob.residuals_and_jacobian(theta)
    rep = analyze(J, prob.names, roles=prob.roles)
    ident = set(rep.identifiable)
    assert {f"tracker.{f}" for f in ("x", "y", "z", "rz", "ry", "rx")} <= ident
    assert {"tracker.marker.x", "tracker.marker.y", "tracker.marker.z"} <= ident
    assert not any(n.startswith(("base.", "tool.")) for n in ident)
    # the absolute zero of joint 1 and its height cannot be seen from an unknown tracker
    assert "theta_offset[1]" in rep.dependent and "d[1]" in rep.dependent
    assert rep.dependent["d[1]"] == ["tracker.z"]
    assert rep.rank == 26          # the same count: tracker and marker replace base and tool


def test_zero_columns_and_scaling_invariance():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((50, 4))
    J = np.column_stack([A[:, 0], 1e6 * A[:, 1], np.zeros(50), A[:, 0] * 3e-4 + A[:, 1] * 2,
                         A[:, 2], A[:, 3]])
    names = ["a", "b", "zero", "combo", "c", "d"]
    rep = analyze(J, names)
    assert rep.unobservable == ["zero"]
    assert rep.identifiable == ["a", "b", "c", "d"]
    assert rep.dependent["combo"] == ["a", "b"]
    assert rep.combinations["combo"]["a"] == pytest.approx(3e-4, rel=1e-8)
    assert rep.combinations["combo"]["b"] == pytest.approx(2e-6, rel=1e-8)
    assert rep.residual["combo"] < 1e-12
    # unit scaling of a column does not change the answer
    J2 = J.copy()
    J2[:, 4] *= 1e-2
    assert analyze(J2, names).identifiable == rep.identifiable
    d = rep.to_dict()
    assert d["rank"] == 4 and d["unobservable"] == ["zero"] and len(d["sentences"]) == 2
    assert np.isfinite(rep.cond_scaled) and rep.cond_unscaled > 1e5


def test_priority_is_stable_and_overridable():
    names = ["tool.x", "base.x", "d[1]", "tracker.x"]
    J = np.tile(np.arange(1.0, 11.0)[:, None], (1, 4))         # four identical columns
    assert analyze(J, names).identifiable == ["d[1]"]
    roles = ["tool", "base", "length", "instrument"]
    assert analyze(J, names, roles=roles).identifiable == ["tracker.x"]
    assert list(default_priority(names, roles)) == [3, 2, 1, 0]
    assert analyze(J, names, priority=[0, 1, 2, 3]).identifiable == ["tool.x"]


def test_nearly_dependent_columns_use_the_tolerance():
    rng = np.random.default_rng(3)
    a = rng.standard_normal(100)
    b = rng.standard_normal(100)
    J = np.column_stack([a, a + 1e-10 * b])
    rep = analyze(J, ["p", "q"])
    assert rep.identifiable == ["p"] and rep.dependent["q"] == ["p"]
    rep = analyze(J, ["p", "q"], tol=1e-12)
    assert rep.identifiable == ["p", "q"]
    J = np.column_stack([a, a + 1e-3 * b])
    assert analyze(J, ["p", "q"]).identifiable == ["p", "q"]


def _same_report(a, b, tol=1e-10):
    assert a.identifiable == b.identifiable and a.unobservable == b.unobservable
    assert a.dependent == b.dependent and a.rank == b.rank
    for n, comb in a.combinations.items():
        for k, c in comb.items():
            assert b.combinations[n][k] == pytest.approx(c, rel=tol, abs=1e-12)
    assert np.allclose(a.singular_values, b.singular_values, rtol=0,
                       atol=tol * a.singular_values[0])
    assert np.allclose(a.column_scale, b.column_scale, rtol=tol, atol=0)
    assert a.cond_scaled == pytest.approx(b.cond_scaled, rel=1e-8)
    assert a.cond_unscaled == pytest.approx(b.cond_unscaled, rel=1e-8)


def test_the_compressed_triangle_gives_the_same_report():
    """analyze(J) == analyze(R) for J = Q R: the analysis depends only on J^T J.

    A tall J (tiled QR inside analyze), its triangle from StackedProblem.compressed (never
    forming J), and the same triangle with weights all give one report.
    """
    robot = puma()
    rng = np.random.default_rng(4)
    blk = simulate_positions(robot, random_configurations(robot, 1500, rng), rng, 1e-5,
                             [1, 0.5, 0.2, 0.1, 0.2, 0.3], [0.01, 0.02, 0.03])
    prob, theta = stack(robot, [blk])
    _, J = prob.residuals_and_jacobian(theta)
    ref = analyze(J, prob.names, roles=prob.roles)
    assert ref.rank == 26
    tri = prob.compressed(theta)
    assert tri.R.shape == (45, 45)
    _same_report(ref, analyze(tri.R, prob.names, roles=prob.roles))
    w = rng.uniform(0.5, 1.0, J.shape[0])
    Jw = J * np.sqrt(w)[:, None]
    _same_report(analyze(Jw, prob.names, roles=prob.roles),
                 analyze(prob.compressed(theta, w).R, prob.names, roles=prob.roles))


@pytest.mark.parametrize("hayati,pose,expected", [
    (False, True, 29), (False, False, 26), (True, True, 30), (True, False, 27)])
def test_counts_from_many_measurements(hayati, pose, expected):
    """The theory's counts hold with thousands of rows (the tiled path of analyze)."""
    robot = puma(hayati)
    J, names, roles = robot_jacobian(robot, pose, n=1200)
    rep = analyze(J, names, roles=roles)
    assert rep.rank == expected
    assert rep.dependent["d[3]"] == ["d[2]"]


def test_unscaled_analysis_reports_dependent_columns() -> None:
    """``scale=False`` with both a base set and a dependent column: the coefficients come
    in parameter units (the columns divided by one common norm, so it cancels)."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 20))
    J = np.column_stack([a, b, 2.0 * a - 0.5 * b])
    rep = analyze(J, ["a", "b", "c"], scale=False)
    assert rep.identifiable == ["a", "b"]
    assert rep.combinations["c"] == pytest.approx({"a": 2.0, "b": -0.5})
    scaled = analyze(J, ["a", "b", "c"])
    assert rep.combinations["c"] == pytest.approx(scaled.combinations["c"])
    assert rep.cond_unscaled == pytest.approx(scaled.cond_unscaled)
