"""The calibrated URDF is a minimal diff of its input: only changed <origin> numbers differ."""

from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np
import pytest

from kincal.motion.ik import random_q
from kincal.robots.urdf import load_urdf, write_calibrated_urdf

ODD = """<?xml version='1.0' encoding='utf-8'?>\r
<!-- a hand-written URDF: single quotes, rpy before xyz, a joint inside a comment:\r
  <joint name='j2' type='revolute'><origin xyz='9 9 9'/></joint>  -->\r
<robot name='odd'>\r
  <link name='base'/>   <link name='l1'/>\r
  <link name='l2'/>\r
  <joint name='j1' type='revolute'>\r
    <origin rpy='0 0 0'   xyz='0 0 0.30' />  <!-- shoulder height: 300 mm -->\r
    <parent link='base'/><child link='l1'/>\r
    <axis xyz='0 0 1'/><limit lower='-3' upper='3' effort='1' velocity='1'/>\r
  </joint>\r
  <joint name='j2' type='revolute'>\r
    <parent link='l1'/>\r
    <child link='l2'/>\r
    <origin xyz="0.5 0 0"/>\r
    <axis xyz='0 1 0'/><limit lower='-3' upper='3' effort='1' velocity='1'/>\r
  </joint>\r
</robot>\r
"""


def _changed(a: str, b: str) -> list[str]:
    return [ln for ln in difflib.unified_diff(a.splitlines(), b.splitlines(), n=0, lineterm="")
            if ln[:1] in "+-" and not ln.startswith(("+++", "---"))]


def test_only_the_changed_origin_numbers_differ(tmp_path):
    src = tmp_path / "odd.urdf"
    src.write_bytes(ODD.encode())
    robot = load_urdf(src, "base", "l2")
    cal = robot.with_params({"j2.origin.x": 0.5012, "j1.offset": 0.0})
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(src, cal, out)
    new = out.read_bytes().decode()
    assert new.count("\r\n") == ODD.count("\r\n")
    changed = _changed(ODD, new)
    assert changed == ['-    <origin xyz="0.5 0 0"/>', '+    <origin xyz="0.5012 0 0"/>']
    back = load_urdf(out, "base", "l2")
    q = np.array([[0.3, -0.7], [1.0, 2.0]])
    assert np.abs(back.fk(q) - cal.fk(q)).max() < 1e-15
    # nothing calibrated: the file comes back byte for byte
    write_calibrated_urdf(src, robot, out)
    assert out.read_bytes() == src.read_bytes()


def test_an_encoder_offset_adds_only_the_rpy_numbers_it_needs(tmp_path):
    src = tmp_path / "odd.urdf"
    src.write_bytes(ODD.encode())
    robot = load_urdf(src, "base", "l2")
    cal = robot.with_params({"j1.offset": 0.01, "j2.offset": -0.02})
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(src, cal, out)
    changed = _changed(ODD, out.read_bytes().decode())
    note = "  <!-- shoulder height: 300 mm -->"
    assert sorted(changed) == sorted(["-    <origin rpy='0 0 0'   xyz='0 0 0.30' />" + note,
                                      "-    <origin xyz=\"0.5 0 0\"/>",
                                      "+    <origin rpy='0 0 0.01'   xyz='0 0 0.30' />" + note,
                                      "+    <origin xyz=\"0.5 0 0\" rpy=\"0 -0.02 0\"/>"])


SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def test_tiago_calibrated_urdf_changes_only_chain_origins(tmp_path):
    urdf = SHARED / "tiago_mocap" / "tiago_48_schunk.urdf"
    if not urdf.is_file():
        pytest.skip(f"real data not found: {urdf}")
    robot = load_urdf(urdf, tip_link="wrist_ft_tool_link")
    rng = np.random.default_rng(3)
    free = [i for i, n in enumerate(robot.param_names) if not n.startswith(("base.", "tool."))]
    v = robot.param_values.copy()
    v[free] += rng.normal(0, 1e-3, len(free))
    cal = robot.with_params(v)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(urdf, cal, out)
    changed = _changed(urdf.read_text(), out.read_text())
    joints = {n.split(".")[0] for n in robot.param_names if "." in n} - {"base", "tool"}
    assert changed and all("<origin" in ln for ln in changed)
    assert len(changed) == 2 * len(joints)
    back = load_urdf(out, tip_link="wrist_ft_tool_link")
    q = random_q(robot, 50, np.random.default_rng(4))
    assert np.abs(back.fk(q) - cal.fk(q)).max() < 1e-12


def test_a_missing_origin_is_added_with_the_files_line_ending():
    """A CRLF URDF stays CRLF where an <origin> is inserted; an LF file stays LF."""
    from kincal.robots.urdf_text import set_origin

    def fmt(values):
        return " ".join(repr(float(v)) for v in values)

    lines = ['<robot name="r">', '  <joint name="j1" type="revolute">', '    <parent link="a"/>',
             '    <child link="b"/>', "  </joint>", "</robot>", ""]
    for eol in ("\r\n", "\n"):
        text = eol.join(lines)
        out = set_origin(text, "j1", [0.0, 0.0, 0.1], [0.0, 0.0, 0.0], fmt)
        assert out == text.replace(f'type="revolute">{eol}',
                                   f'type="revolute">{eol}    <origin xyz="0.0 0.0 0.1"/>{eol}')
        assert out.count("\n") == out.count(eol) == text.count(eol) + 1
