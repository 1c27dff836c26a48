"""Kutzbach/Grübler mobility against textbook counts."""

from __future__ import annotations

import pytest

from kincal.errors import KincalError
from kincal.parallel.mobility import Joint, Mechanism, dual_scara_thesis, mobility, planar_five_bar


def test_thesis_dual_scara_has_four_freedoms() -> None:
    m = dual_scara_thesis()
    assert (len(m.links), len(m.joints), m.loops()) == (6, 6, 1)
    assert m.kutzbach() == 4 and m.grubler() == 4


def test_planar_five_bar_has_two_freedoms() -> None:
    m = planar_five_bar()
    assert m.kutzbach() == 2 and m.grubler() == 2 and m.loops() == 1


def test_four_bar_and_stewart_platform() -> None:
    four_bar = [("g", "a", 1), ("a", "b", 1), ("b", "c", 1), ("c", "g", 1)]
    assert mobility(["g", "a", "b", "c"], four_bar) == 1
    # Gough-Stewart: ground, platform, 6 legs of 2 parts; 6 U, 6 P, 6 S -> F = 6
    links = ["ground", "platform"] + [f"{p}{i}" for i in range(6) for p in ("lo", "up")]
    joints = []
    for i in range(6):
        joints += [("ground", f"lo{i}", 2), (f"lo{i}", f"up{i}", 1), (f"up{i}", "platform", 3)]
    m = Mechanism(tuple(links), tuple(Joint(f"j{k}", (a, b), f) for k, (a, b, f)
                                      in enumerate(joints)), "spatial")
    assert m.kutzbach() == 6 and m.grubler() == 6 and m.loops() == 5
    assert mobility(14, joints, "spatial") == 6


def test_bad_mechanisms_are_named() -> None:
    with pytest.raises(KincalError, match="joint 'J1' names unknown link 'z'"):
        mobility(["a", "b"], [("a", "z", 1)])
    with pytest.raises(KincalError, match="freedom must be between 1 and 2"):
        mobility(["a", "b"], [("a", "b", 3)])
    with pytest.raises(KincalError, match="space must be one of"):
        Mechanism(("a",), (), "hyper")
