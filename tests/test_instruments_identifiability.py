"""The identifiability report names what each instrument cannot see.

Noise-free simulations on the nominal PUMA 560; the analysis runs on the stacked
Jacobian at the truth.  "Surveyed" instruments have their station parameters removed
from the candidates (known from a survey).  Structural dependencies of the PUMA itself
(``base.z``/``d[1]``, ``base.rz``/``theta_offset[1]``, ``d[3]``/``d[2]``, last link/tool)
appear in every list; the tests look at what the instrument adds or removes.
"""

from __future__ import annotations

import numpy as np
from test_instruments_support import NOMINAL

from kincal.identify.identifiability import IdentifiabilityReport, analyze
from kincal.measure import instruments as S
from kincal.measure.base import stack

BASE = {f"base.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")}
TOOL_ROT = {"tool.rx", "tool.ry", "tool.rz"}


def report(blocks: list, surveyed: tuple[str, ...] = ()) -> IdentifiabilityReport:
    prob, theta = stack(NOMINAL, blocks)
    _, J = prob.residuals_and_jacobian(theta)
    keep = [i for i, n in enumerate(prob.names) if not n.startswith(surveyed)]
    return analyze(J[:, keep], [prob.names[i] for i in keep],
                   roles=[prob.roles[i] for i in keep])


def robot_hidden(rep: IdentifiabilityReport) -> set[str]:
    return {p for p in rep.not_identifiable if p in NOMINAL.param_names}


def lengths(names: set[str]) -> set[str]:
    return {p for p in names if NOMINAL.param_units[NOMINAL.param_index(p)] == "m"}


def sim(fn, n: int = 40, **opts) -> list:
    return fn(NOMINAL, np.random.default_rng(1), n, 0.0, **opts)[0]


def test_range_one_station_cannot_fix_the_base_orientation() -> None:
    one = report(sim(S.simulate_range, stations=1), surveyed=("range.s",))
    two = report(sim(S.simulate_range, stations=2), surveyed=("range.s",))
    three = report(sim(S.simulate_range, stations=3), surveyed=("range.s",))
    # rotations about a single (surveyed) station are invisible: 3 more hidden directions
    assert {"base.rx", "base.ry"} <= robot_hidden(one)
    assert len(robot_hidden(one)) - len(robot_hidden(three)) == 3
    # two stations leave the rotation about their common line
    assert len(robot_hidden(two)) - len(robot_hidden(three)) == 1
    # three surveyed stations see the base orientation (rz only through joint 1's offset)
    assert {"base.rx", "base.ry", "base.x", "base.y"}.isdisjoint(robot_hidden(three))
    said = " ".join(one.describe())
    assert "base.rx" in said and "base.ry" in said


def test_range_with_unknown_stations_hides_the_base_frame() -> None:
    rep = report(sim(S.simulate_range))
    assert BASE <= robot_hidden(rep)
    assert {n for n in rep.names if n.startswith("range.")} <= set(rep.identifiable)


def test_angle_instruments_cannot_see_the_scale() -> None:
    """Theodolites and fixed cameras with unknown poses lose one length (the scale) that
    surveyed instruments, or ranges, recover."""
    for fn, prefix in ((S.simulate_bearing, "theodolite."), (S.simulate_camera, "camera.")):
        blocks = sim(fn)
        free = report(blocks)
        ranges = report(sim(S.simulate_range))
        scale = lengths(robot_hidden(free) - robot_hidden(ranges))
        assert len(scale) == 1, (prefix, scale)
        surveyed = report(blocks, surveyed=(prefix.rstrip(".") + ".t", prefix + "c"))
        assert scale.isdisjoint(robot_hidden(surveyed))
        assert BASE <= robot_hidden(free)


def test_hand_camera_sees_the_hand_eye_pose_but_not_the_base() -> None:
    blocks = sim(S.simulate_camera, 15, mount="hand")
    rep = report(blocks)
    assert BASE <= robot_hidden(rep)                      # the target pose takes its place
    assert {"tool.y", "tool.ry"} <= set(rep.identifiable)  # camera pose beyond the last link
    known_target = report(blocks, surveyed=("camera.target",))
    assert {"base.x", "base.y", "base.rx", "base.ry"}.isdisjoint(robot_hidden(known_target))
    # the target's known geometry gives the scale: no chain length lost beyond the
    # structural d[1]/base.z and d[3]/d[2], and the tool offsets the last link covers
    assert lengths(robot_hidden(rep)) <= BASE | {"d[1]", "d[3]", "tool.x", "tool.z"}


def test_plane_contacts_see_one_direction_per_plane() -> None:
    one = report(sim(S.simulate_plane, 80, planes=1, known=True))
    hidden = robot_hidden(one)
    assert len({"base.x", "base.y", "base.z"} - hidden) <= 1  # only along the normal
    three = report(sim(S.simulate_plane, 80, planes=3, known=True))
    four = report(sim(S.simulate_plane, 80, planes=4, known=True))
    # three planes: scaling about their corner keeps every contact: one direction lost
    assert len(robot_hidden(three)) - len(robot_hidden(four)) == 1
    assert {"base.x", "base.y"}.isdisjoint(robot_hidden(four))
    # unknown planes absorb the base frame (like unknown range stations) and, through
    # their offsets, the scale: one length more than the ranges hide
    unknown = report(sim(S.simulate_plane, 80, planes=6))
    ranges = report(sim(S.simulate_range))
    assert BASE <= robot_hidden(unknown)
    assert len(lengths(robot_hidden(unknown)) - lengths(robot_hidden(ranges))) == 1


def test_fixture_sees_the_base_but_not_the_tool_orientation() -> None:
    rep = report(sim(S.simulate_fixture))
    assert TOOL_ROT <= robot_hidden(rep)
    assert {"base.x", "base.y", "base.rx", "base.ry"}.isdisjoint(robot_hidden(rep))
    # the robot's tool origin at the wrist centre (marker="tool", tool = 0): joints 4-6
    # do not move the point, so the wrist constants are invisible
    wrist = report(sim(S.simulate_fixture, marker="tool"))
    assert {"theta_offset[4]", "theta_offset[5]", "alpha[4]", "alpha[5]"} <= \
        robot_hidden(wrist)
