"""Robot programs as real cells write them: FANUC backups in German, RAPID programs of
several modules, configuration monitoring off, and Euler angles at gimbal lock.

The fixtures in ``tests/data/programs`` are written from the vendors' documented syntax
(``zelle3.ls``: a German FANUC backup with ``KONFIG``, an untaught point, a joint point and
an ``RX ... RR`` point; ``rapid_backup``: an IRC5 backup layout, ``RAPID/TASK1/PROGMOD`` with
the tool and work object in ``CalibData.mod``, ``ConfL \\Off`` over placeholder
confdata, ``RelTool``).  What the controller does with a filtered file is computed here
independently of the filter: the written numbers are parsed with this file's own regular
expressions, turned into the flange pose with numpy (quaternion and W-P-R formulas written
out below), solved by the nominal robot's closed-form IK on the branch the program asks
for, and the calibrated robot at those joints must reach the original TCP.
"""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.measure.simulate import perturb_robot
from kincal.motion.ik_wrist import ik_spherical_wrist
from kincal.robots.controller import controller_map
from kincal.robots.files import load_serial_robot, write_robot_yaml
from kincal.spatial import rpy_near

DATA = Path(__file__).parent / "data" / "programs"
BACKUP = DATA / "rapid_backup"
TASK = BACKUP / "RAPID" / "TASK1"


# ------------------------------------------------------------------ independent formulas
def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _wpr(x, y, z, w, p, r):
    """FANUC X Y Z [mm] W P R [deg]: ``Trans Rz(R) Ry(P) Rx(W)`` (fixed X-Y-Z angles)."""
    T = np.eye(4)
    T[:3, :3] = _rz(math.radians(r)) @ _ry(math.radians(p)) @ _rx(math.radians(w))
    T[:3, 3] = np.array([x, y, z]) * 1e-3
    return T


def _quat(p, q):
    """ABB pos [mm] and quaternion [q1 = w, q2, q3, q4] as a 4x4 [m]."""
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = [[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]]
    T[:3, 3] = np.asarray(p) * 1e-3
    return T


_LS_POINT = re.compile(r"P\[(\d+)[^\]]*\]\{\s*GP1:\s*UF : (\d+), UT : (\d+),\s*\w+ : '([^']*)',"
                       r"\s*X =\s*(\S+)\s*mm,\s*Y =\s*(\S+)\s*mm,\s*Z =\s*(\S+)\s*mm,"
                       r"\s*W =\s*(\S+)\s*deg,\s*P =\s*(\S+)\s*deg,\s*R =\s*(\S+)\s*deg")
_ROBTARGET = re.compile(r"robtarget (\w+):=\[\[([^\]]*)\],\[([^\]]*)\],\[([^\]]*)\]")


def _ls_points(text):
    return {int(m.group(1)): (m.group(4), [float(v) for v in m.groups()[4:]])
            for m in _LS_POINT.finditer(text)}


def _robtargets(text):
    return {m.group(1): ([float(v) for v in m.group(2).split(",")],
                         [float(v) for v in m.group(3).split(",")],
                         [int(v) for v in m.group(4).split(",")])
            for m in _ROBTARGET.finditer(text)}


def _branches(robot, F):
    """All closed-form nominal solutions of flange pose F: (B, 6) model joints."""
    sol = ik_spherical_wrist(robot, F[None])
    return sol.q[0][sol.reachable[0]]


def _nearest_axes(cands, prev, lo=-400.0, hi=400.0):
    """ABB with configuration monitoring off: of the solutions (axes, deg), each axis
    turned by whole turns towards ``prev`` within +-400 deg, the one nearest ``prev``."""
    best, dist = None, math.inf
    for c in cands:
        c = c.copy()
        for j in (0, 3, 5):
            for k in range(-2, 3):
                v = c[j] + 360.0 * k
                if lo <= v <= hi and abs(v - prev[j]) < abs(c[j] - prev[j]):
                    c[j] = v
        d = np.linalg.norm(c - prev)
        if d < dist:
            best, dist = c, d
    return best


@pytest.fixture(scope="module")
def robots(tmp_path_factory):
    """m10ia and irb120, each with 1 mm / 0.05 deg errors (a robot file)."""
    folder = tmp_path_factory.mktemp("robots")
    out = {}
    for name in ("m10ia", "irb120"):
        nom = load_serial_robot(name)
        cal = perturb_robot(nom, np.random.default_rng(7)).with_name(f"{name}_cal")
        write_robot_yaml(cal, folder / f"{name}_cal.yaml")
        out[name] = (nom, load_serial_robot(str(folder / f"{name}_cal.yaml")),
                     str(folder / f"{name}_cal.yaml"))
    return out


# ------------------------------------------------------------------ FANUC, German backup
FANUC_AXES = {1: (10, 20, -10, 30, -60, 200), 2: (-25, 35, 5, -40, 45, -30)}
UF2 = _wpr(800, 100, -300, 0, 0, 30)
UT3 = _wpr(0, 0, 120, 0, 0, 0)


def _fanuc_check(nom, cal, old_text, new_text):
    """Each filtered point, solved by the nominal IK on its configuration (the branch
    nearest the axes it was taught with, whole turns of J1/J4/J6 from its turn numbers),
    brings the calibrated robot's TCP to the original TCP."""
    cmap = controller_map(nom, "fanuc")
    old, new = _ls_points(old_text), _ls_points(new_text)
    for k, axes in FANUC_AXES.items():
        F = UF2 @ _wpr(*new[k][1]) @ np.linalg.inv(UT3)
        cands = cmap.to_axes(_branches(nom, F))
        conf = new[k][0]
        turns = [int(v) for v in conf.split(",")[1:]]
        for j, t in zip((0, 3, 5), turns, strict=True):    # turn t: (-180 + 360 t, 180 + 360 t]
            cands[:, j] = cands[:, j] - 360.0 * np.floor((cands[:, j] + 180.0) / 360.0) + 360 * t
        flags = conf.split(",")[0].split()
        wrist_ok = (cands[:, 4] > 0) if flags[0] == "F" else (cands[:, 4] <= 0)
        cands = cands[wrist_ok]
        best = cands[np.argmin(np.abs(cands - np.array(axes)).max(axis=1))]
        assert np.abs(best - np.array(axes)).max() < 3.0, (k, best)   # the taught branch
        q = cmap.to_model(best)
        tcp = cal.fk(q) @ UT3
        want = UF2 @ _wpr(*old[k][1])
        assert np.linalg.norm(tcp[:3, 3] - want[:3, 3]) < 5e-6, k      # 3 decimals written


def test_german_backup_konfig_is_read_as_config(tmp_path, robots, capsys):
    nom, cal, cal_path = robots["m10ia"]
    src = DATA / "zelle3.ls"
    english = tmp_path / "zelle3_en.ls"
    english.write_bytes(src.read_bytes().replace(b"KONFIG :", b"CONFIG :"))
    frames = DATA / "fanuc_frames.yaml"
    for program, out in ((src, tmp_path / "de.ls"), (english, tmp_path / "en.ls")):
        code, _, err = run(capsys, "filter", program, "--robot", cal_path, "--nominal", "m10ia",
                           "--frames", frames, "-o", out, "--csv", tmp_path / "t.csv")
        assert code == 1 and "P[5]" in err and "RX ... RR" in err     # listed, not rejected
    de, en = (tmp_path / "de.ls").read_bytes(), (tmp_path / "en.ls").read_bytes()
    assert de == en.replace(b"CONFIG :", b"KONFIG :")
    _fanuc_check(nom, cal, src.read_text("latin-1"), de.decode("latin-1"))
    # the reader's configurations: flags and turn numbers of KONFIG
    from kincal.compensation.programs.fanuc import read_ls

    conf = {t.name: t.config for t in read_ls(str(src)).targets}
    assert conf["P[1]"].text == "'N U T, 0, 0, 1'" and conf["P[1]"].wrist == -1
    assert conf["P[1]"].intervals[5] == pytest.approx((math.radians(180), math.radians(540)))
    assert conf['P[2:"Schweisspunkt"]'].wrist == 1 and conf["P[3]"] is None


def test_untaught_joint_and_rx_points_are_listed_and_the_rest_filtered(tmp_path, robots,
                                                                       capsys):
    nom, cal, cal_path = robots["m10ia"]
    text = (DATA / "zelle3.ls").read_bytes()
    rows = {}
    for variant, body in (("rx_used", text),
                          ("no_rx", text.replace(b"L P[5] 100mm/sek", b"! P5 100mm/sek")),
                          ("untaught_used", text.replace(b"//L P[3]", b"L P[3]  "))):
        src = tmp_path / f"{variant}.ls"
        src.write_bytes(body)
        code, _, err = run(capsys, "filter", src, "--robot", cal_path, "--nominal", "m10ia",
                           "--frames", DATA / "fanuc_frames.yaml", "-o", tmp_path / "o.ls",
                           "--csv", tmp_path / f"{variant}.csv")
        rows[variant] = (code, {r.split(",")[0]: r for r in
                                (tmp_path / f"{variant}.csv").read_text().splitlines()[1:]})
    code, r = rows["rx_used"]
    assert code == 1 and ",not filtered," in r["P[5]"] and "RX ... RR" in r["P[5]"]
    assert ",unused," in r["P[3]"] and "not taught" in r["P[3]"]
    assert ",kept," in r["P[4]"] and "need no filtering" in r["P[4]"]
    assert ",filtered," in r["P[1]"]
    assert rows["no_rx"][0] == 0                    # every motion target filtered or kept
    code, r = rows["untaught_used"]
    assert code == 1 and ",not filtered," in r["P[3]"] and "not taught" in r["P[3]"]
    assert ",filtered," in r["P[1]"]


# ------------------------------------------------------------------ RAPID, several modules
TOOL = _quat([0, 0, 150], [0.9659258, 0, 0.258819, 0])
WOBJ = _quat([400, -100, 50], [0.9238795, 0, 0, 0.3826834]) @ _quat([10, 20, 0], [1, 0, 0, 0])
RAPID_AXES = {"pApproach": (-20, 10, 10, 20, 50, -30), "pWeld10": (-15, 25, 5, 10, 45, -20),
              "pWeld20": (-5, 28, 3, 5, 48, -10), "pWeld30": (5, 27, 4, -5, 50, 0)}


def _rapid_check(nom, cal, old_text, new_text):
    """Monitored targets: the nominal branch with the written confdata quadrants; targets
    under ``ConfL \\Off``: the nominal branch nearest the previous target's axes (what the
    controller does).  The calibrated robot there reaches the original TCP."""
    cmap = controller_map(nom, "abb")
    old, new = _robtargets(old_text), _robtargets(new_text)
    prev = None
    for name in ("pApproach", "pWeld10", "pWeld20", "pWeld30"):
        pos, q, cf = new[name]
        F = WOBJ @ _quat(pos, q) @ np.linalg.inv(TOOL)
        cands = cmap.to_axes(_branches(nom, F))
        if any(cf):
            quad = np.floor(cands[:, [0, 3, 5]] / 90.0)
            cands = cands[np.all(quad == np.array(cf[:3]), axis=1)]
            assert len(cands) >= 1, name
            best = cands[np.argmin(np.abs(cands - np.array(RAPID_AXES[name])).max(axis=1))]
        else:
            assert cf == [0, 0, 0, 0]          # placeholder kept: the controller ignores it
            best = _nearest_axes(cands, prev)
        assert np.abs(best - np.array(RAPID_AXES[name])).max() < 3.0, (name, best)
        tcp = cal.fk(cmap.to_model(best)) @ TOOL
        want = WOBJ @ _quat(*old[name][:2])
        assert np.linalg.norm(tcp[:3, 3] - want[:3, 3]) < 12e-6, name   # 2 decimals of mm
        prev = best


def _decimals(text, pattern):
    return max(len(v.split(".")[1]) if "." in v else 0 for v in re.findall(pattern, text))


def test_rapid_backup_folder_tool_in_calibdata_and_confl_off(tmp_path, robots, capsys):
    nom, cal, cal_path = robots["irb120"]
    out = tmp_path / "out"
    code, _, err = run(capsys, "filter", BACKUP, "--robot", cal_path, "--nominal", "irb120",
                       "-o", out, "--csv", tmp_path / "t.csv")
    assert code == 0, err
    rows = {r.split(",")[0]: r for r in (tmp_path / "t.csv").read_text().splitlines()[1:]}
    assert all(",filtered," in rows[n] for n in RAPID_AXES)
    assert "ConfL\\Off: branch nearest the previous target" in rows["pWeld20"]
    assert "Off" not in rows["pWeld10"]
    assert ",kept," in rows["RelTool(pApproach...) line 18"]
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.*")) == \
        ["PROGMOD/CalibData.mod", "PROGMOD/MainModule.mod", "SYSMOD/user.sys"]
    assert (out / "PROGMOD/CalibData.mod").read_bytes() == \
        (TASK / "PROGMOD/CalibData.mod").read_bytes()
    old = (TASK / "PROGMOD/MainModule.mod").read_text("latin-1")
    new = (out / "PROGMOD/MainModule.mod").read_text("latin-1")
    _rapid_check(nom, cal, old, new)
    # no finer than the file: mm with 2 decimals, quaternions with 7
    assert _decimals(new, r"\[\[([-\d.]+),") == 2
    assert _decimals(new, r"\],\[(0?\.\d+|-?\d\.\d+)") <= 7
    # the same program as two files, and as one file with --frames naming tool and wobj
    two = tmp_path / "two"
    code, _, err = run(capsys, "filter", TASK / "PROGMOD/MainModule.mod",
                       TASK / "PROGMOD/CalibData.mod", "--robot", cal_path,
                       "--nominal", "irb120", "-o", two)
    assert code == 0, err
    assert (two / "MainModule.mod").read_bytes() == (out / "PROGMOD/MainModule.mod").read_bytes()
    frames = tmp_path / "frames.yaml"
    frames.write_text("units: {length: mm, angle: deg}\n"
                      "tool: {tGun: {x: 0, y: 0, z: 150, rx: 0, ry: 29.9999958, rz: 0}}\n"
                      "base: {wFixture: {x: 392.9289329, y: -78.7867963, z: 50, rx: 0, ry: 0, "
                      "rz: 44.999998}}\n")     # CalibData's quaternions as angles, uframe*oframe
    code, _, err = run(capsys, "filter", TASK / "PROGMOD/MainModule.mod", "--robot", cal_path,
                       "--nominal", "irb120", "--frames", frames, "-o", tmp_path / "f.mod")
    assert code == 0, err
    _rapid_check(nom, cal, old, (tmp_path / "f.mod").read_text("latin-1"))


def test_rapid_module_without_its_tool_lists_targets_and_names_the_tool(tmp_path, robots,
                                                                         capsys):
    _, _, cal_path = robots["irb120"]
    code, _, err = run(capsys, "filter", TASK / "PROGMOD/MainModule.mod", "--robot", cal_path,
                       "--nominal", "irb120", "-o", tmp_path / "o.mod",
                       "--csv", tmp_path / "t.csv")
    assert code == 1
    assert "'tgun' is declared in no module read" in err.lower() and "CalibData.mod" in err
    assert "tool0" not in err
    rows = (tmp_path / "t.csv").read_text().splitlines()[1:]
    assert sum(",not filtered," in r for r in rows) == 4


def test_rapid_run_time_and_missing_targets_are_listed(tmp_path, robots, capsys):
    _, _, cal_path = robots["irb120"]
    src = tmp_path / "Runtime.mod"
    src.write_text("MODULE Runtime\n"
                   "  CONST robtarget pA:=[[450,0,544],[0.5,0,0.8660254,0],[0,0,0,0],"
                   "[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
                   "  VAR robtarget pCur;\n"
                   "  PROC main()\n"
                   "    MoveL pA, v100, fine, tool0;\n"
                   "    pCur := CRobT(\\Tool:=tool0);\n"
                   "    MoveL pCur, v100, fine, tool0;\n"
                   "    MoveL pElsewhere, v100, fine, tool0;\n"
                   "    MoveL Offs(pA, 0, 0, 20), v100, fine, tool0;\n"
                   "  ENDPROC\nENDMODULE\n")
    code, _, _ = run(capsys, "filter", src, "--robot", cal_path, "--nominal", "irb120",
                     "-o", tmp_path / "o.mod", "--csv", tmp_path / "t.csv")
    assert code == 1
    rows = {r.split(",")[0]: r for r in (tmp_path / "t.csv").read_text().splitlines()[1:]}
    assert ",filtered," in rows["pA"]
    assert ",not filtered," in rows["pCur"] and "run time" in rows["pCur"]
    assert ",not filtered," in rows["pElsewhere"] and "no module read" in rows["pElsewhere"]
    assert ",kept," in rows["Offs(pA...) line 9"]


# ------------------------------------------------------------------ property: the corpus
CORPUS = [("zelle3.ls", "m10ia", "fanuc_frames.yaml"), ("rapid_backup", "irb120", None),
          ("gimbal.ls", "m10ia", None)]


@pytest.mark.parametrize("case", CORPUS, ids=[c[0] for c in CORPUS])
def test_corpus_identity_is_byte_identical_and_calibration_changes_only_numbers(
        case, tmp_path, robots, capsys):
    program, robot, frames = case
    src = tmp_path / program
    (shutil.copytree if (DATA / program).is_dir() else shutil.copy)(DATA / program, src)
    extra = ["--frames", DATA / frames] if frames else []
    files = sorted(p for p in src.rglob("*") if p.suffix in (".ls", ".mod", ".sys")) \
        if src.is_dir() else [src]
    for which in ("identity", "calibrated"):
        out = tmp_path / which / ("out" if src.is_dir() else program)
        run(capsys, "filter", src, "--robot", robot if which == "identity" else robots[robot][2],
            "--nominal", robot, "-o", out, *extra)
        root = src / "RAPID" / "TASK1" if src.is_dir() else src.parent
        changed = 0
        for f in files:
            new = (out / f.relative_to(root)).read_bytes() if src.is_dir() else out.read_bytes()
            old = f.read_bytes()
            if which == "identity":
                assert new == old, f.name
                continue
            for a, b in zip(old.split(b"\n"), new.split(b"\n"), strict=True):
                if a != b:       # only numbers differ, and only on target lines
                    changed += 1
                    assert re.sub(rb"[-+.\d ]", b"", a) == re.sub(rb"[-+.\d ]", b"", b), (a, b)
                    assert re.search(rb"robtarget|X =|W =", a), a
        assert which == "identity" or changed > 0


# ------------------------------------------------------------------ gimbal lock
def _angle_change(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0).max()


def test_rpy_near_at_gimbal_lock_changes_angles_by_the_correction_only():
    """At pitch = +-90 deg a rotation about the world z axis or about the pitch axis is a
    change the angles can follow: 0.1 deg of it changes no angle by more than 0.1 deg
    (and the numbers reproduce the rotation); a crossing of the pole keeps roll and yaw."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        old = np.array([rng.uniform(-180, 180), rng.choice([-90.0, 90.0]), rng.uniform(-180, 180)])
        R0 = _rz(math.radians(old[2])) @ _ry(math.radians(old[1])) @ _rx(math.radians(old[0]))
        for axis in (np.array([0, 0, 1.0]), _rz(math.radians(old[2])) @ np.array([0, 1.0, 0])):
            for sign in (1, -1):
                th = math.radians(0.1 * sign)
                K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]],
                              [-axis[1], axis[0], 0]])
                Rc = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
                R1 = Rc @ R0
                new = np.degrees(rpy_near(R1, np.radians(old), math.radians(5e-5)))
                back = _rz(math.radians(new[2])) @ _ry(math.radians(new[1])) @ \
                    _rx(math.radians(new[0]))
                assert np.abs(back - R1).max() < 1e-9
                assert _angle_change(new, old) <= 0.1 + 1e-9, (old, new)


def test_rpy_near_off_the_pole_is_the_closer_of_the_two_exact_solutions():
    rng = np.random.default_rng(6)
    for _ in range(200):
        r, p, y = rng.uniform(-180, 180), rng.uniform(-89, 89), rng.uniform(-180, 180)
        R = _rz(math.radians(y)) @ _ry(math.radians(p)) @ _rx(math.radians(r))
        twin = np.array([r + 180, 180 - p, y + 180])        # the same rotation
        for near in (np.array([r, p, y]) + rng.normal(0, 0.05, 3), twin + rng.normal(0, 0.05, 3),
                     twin - 360.0):
            got = np.degrees(rpy_near(R, np.radians(near)))
            assert np.abs(got - near).max() < 0.2, (near, got)   # numbers stay where they were


def test_fanuc_point_at_p90_keeps_its_numbers_for_a_rotation_about_the_vertical(tmp_path,
                                                                                capsys):
    """A calibration that turns the robot 0.1 deg about its base z axis moves a P = 90
    point's W and R by 0.05 deg each (before: an arbitrary split, tens of degrees)."""
    nom = load_serial_robot("m10ia")
    v = dict(zip(nom.param_names, nom.param_values, strict=True))
    cal = nom.with_params({"base.rz": v["base.rz"] + math.radians(0.1)}).with_name("turned")
    write_robot_yaml(cal, tmp_path / "turned.yaml")
    code, _, err = run(capsys, "filter", DATA / "gimbal.ls", "--robot", tmp_path / "turned.yaml",
                       "--nominal", "m10ia", "-o", tmp_path / "g.ls")
    assert code == 0, err
    old = _ls_points((DATA / "gimbal.ls").read_text("latin-1"))
    new = _ls_points((tmp_path / "g.ls").read_text("latin-1"))
    for k in old:
        assert new[k][1][4] == old[k][1][4] and abs(old[k][1][4]) == 90.0     # P stays
        assert _angle_change(new[k][1][3:], old[k][1][3:]) <= 0.1 + 1e-3, (old[k], new[k])
        assert new[k][1][3:] != old[k][1][3:]


def test_calibrated_urdf_keeps_unchanged_numbers_and_rpy_near_its_own(tmp_path):
    """Only the numbers the calibration changes differ, written without rounding noise, and
    an rpy of (pi, 0.2, pi) stays near pi instead of jumping to -pi."""
    from kincal.robots.urdf import load_urdf, write_calibrated_urdf

    src = tmp_path / "r.urdf"
    src.write_text('<robot name="r">\n  <link name="a"/><link name="b"/><link name="c"/>\n'
                   '  <joint name="j1" type="revolute">\n'
                   '    <origin xyz="0 0 0.3" rpy="1.5707963267948966 0 0"/>\n'
                   '    <parent link="a"/><child link="b"/><axis xyz="0 0 1"/>\n'
                   '    <limit lower="-3" upper="3" effort="1" velocity="1"/>\n  </joint>\n'
                   '  <joint name="j2" type="revolute">\n'
                   '    <origin xyz="0.4 0 0" rpy="3.141592653589793 0.2 3.141592653589793"/>\n'
                   '    <parent link="b"/><child link="c"/><axis xyz="0 0 1"/>\n'
                   '    <limit lower="-3" upper="3" effort="1" velocity="1"/>\n  </joint>\n'
                   '</robot>\n')
    robot = load_urdf(src, "a", "c")
    v = dict(zip(robot.param_names, robot.param_values, strict=True))
    cal = robot.with_params({"j1.origin.ry": v["j1.origin.ry"] + 1e-4,
                             "j2.offset": v["j2.offset"] - 1e-4})
    write_calibrated_urdf(src, cal, tmp_path / "c.urdf")
    text = (tmp_path / "c.urdf").read_text()
    rpys = re.findall(r'rpy="([^"]*)"', text)
    j1 = [float(x) for x in rpys[0].split()]
    # Rx(pi/2) Ry(d) = Rz(d) Rx(pi/2): yaw takes d, roll and pitch keep their text exactly
    assert rpys[0].split()[:2] == ["1.5707963267948966", "0"]
    assert j1[2] == pytest.approx(1e-4, abs=1e-15)
    j2 = [float(x) for x in rpys[1].split()]
    assert np.abs(np.array(j2) - np.array([math.pi, 0.2, math.pi])).max() < 2e-4, j2
    back = load_urdf(tmp_path / "c.urdf", "a", "c")
    q = np.array([[0.3, -0.7], [1.0, 2.0]])
    assert np.abs(back.fk(q) - cal.fk(q)).max() < 1e-12


def test_fanuc_point_crossing_p90_keeps_w_and_r(tmp_path, capsys):
    """A 0.1 deg turn about the pitch axis takes P = 90 to 90.1: written as P 90.100 with
    W and R as they were, not as the other Euler solution (W - 180, 89.9, R + 180)."""
    nom = load_serial_robot("m10ia")
    v = dict(zip(nom.param_names, nom.param_values, strict=True))
    cal = nom.with_params({"base.ry": v["base.ry"] - math.radians(0.1)}).with_name("tilted")
    write_robot_yaml(cal, tmp_path / "tilted.yaml")
    src = tmp_path / "g.ls"
    src.write_bytes((DATA / "gimbal.ls").read_bytes().replace(b"L P[2]", b"! P[2"))
    code, _, err = run(capsys, "filter", src, "--robot", tmp_path / "tilted.yaml",
                       "--nominal", "m10ia", "-o", tmp_path / "o.ls")
    assert code == 0, err
    w, p, r = _ls_points((tmp_path / "o.ls").read_text("latin-1"))[1][1][3:]
    assert (w, r) == (168.02, 0.0) and p == pytest.approx(90.1, abs=1e-3)


def test_a_backup_of_several_tasks_is_refused_in_one_line(tmp_path, capsys):
    for task in ("T_ROB_L", "T_ROB_R"):                 # a YuMi backup: one arm per task
        shutil.copytree(TASK, tmp_path / "bak" / "RAPID" / task)
    code, _, err = run(capsys, "filter", tmp_path / "bak", "--robot", "irb120",
                       "--nominal", "irb120", "-o", tmp_path / "out")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "2 RAPID tasks" in err and "T_ROB_L" in err and not (tmp_path / "out").exists()


def test_extended_axes_in_the_robots_group_are_listed(tmp_path, capsys):
    text = (DATA / "zelle3.ls").read_bytes().replace(
        b"R =  -167.769 deg\r\n", b"R =  -167.769 deg,\r\n\tE1=  1500.000  mm\r\n")
    src = tmp_path / "rail.ls"
    src.write_bytes(text)
    code, _, _ = run(capsys, "filter", src, "--robot", "m10ia", "--nominal", "m10ia",
                     "--frames", DATA / "fanuc_frames.yaml", "-o", tmp_path / "o.ls",
                     "--csv", tmp_path / "t.csv")
    rows = {r.split(",")[0]: r for r in (tmp_path / "t.csv").read_text().splitlines()[1:]}
    assert code == 1 and ",not filtered," in rows["P[1]"] and "E1" in rows["P[1]"]
    assert (tmp_path / "o.ls").read_bytes() == text


def test_rapid_follows_procedure_calls_from_main(tmp_path, robots, capsys):
    """``ConfL \\Off`` in main before a call reaches the moves of the called procedure,
    even when that procedure is written above main: the result is the backup's."""
    nom, cal, cal_path = robots["irb120"]
    main = (TASK / "PROGMOD/MainModule.mod").read_bytes().decode("latin-1")
    head, body = main.split("  PROC main()\r\n")
    body = body.replace("    MoveL pWeld20, v50, z1, tGun\\WObj:=wFixture;\r\n"
                        "    MoveL pWeld30, v50, fine, tGun\\WObj:=wFixture;\r\n"
                        "    ConfL \\On;\r\n", "    weld_seam;\r\n    ConfL \\On;\r\n")
    weld = ("  PROC weld_seam()\r\n    MoveL pWeld20, v50, z1, tGun\\WObj:=wFixture;\r\n"
            "    MoveL pWeld30, v50, fine, tGun\\WObj:=wFixture;\r\n  ENDPROC\r\n\r\n")
    src = tmp_path / "MainModule.mod"
    src.write_bytes((head + weld + "  PROC main()\r\n" + body).encode("latin-1"))
    code, _, err = run(capsys, "filter", src, TASK / "PROGMOD/CalibData.mod", "--robot",
                       cal_path, "--nominal", "irb120", "-o", tmp_path / "out",
                       "--csv", tmp_path / "t.csv")
    assert code == 0, err
    assert "ConfL\\Off" in (tmp_path / "t.csv").read_text()
    out = (tmp_path / "out" / "MainModule.mod").read_text("latin-1")
    _rapid_check(nom, cal, main, out)


# ------------------------------------------------------------------ property: generated programs
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def _fmt(v, decimals, style):
    text = f"{v:.{decimals}f}"
    return f"{v:.{decimals}E}" if style == "exp" else text.rstrip("0").rstrip(".") \
        if style == "trim" else text


@st.composite
def _rapid_modules(draw):
    """A RAPID program in two modules (targets + motions, tool + work object), written in
    varied styles: decimals, trimmed zeros or E notation, spaces, line breaks, comments."""
    n = draw(st.integers(1, 4))
    axes = [np.array([draw(st.floats(-60, 60)), draw(st.floats(-10, 40)), draw(st.floats(-20, 30)),
                      draw(st.floats(-80, 80)), draw(st.floats(20, 80)), draw(st.floats(-80, 80))])
            for _ in range(n)]
    for a in axes:      # 3 deg away from the quadrant boundaries confdata cannot resolve
        a[[0, 3, 5]] += np.where(np.abs((a[[0, 3, 5]] + 45) % 90 - 45) < 3, 3.0, 0.0)
    dec = draw(st.integers(1, 5))
    style = draw(st.sampled_from(["fixed", "trim", "exp"]))
    sep = draw(st.sampled_from([",", ", ", " , "]))
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    off = [False] + draw(st.lists(st.booleans(), min_size=n - 1, max_size=n - 1))  # from a
    # known position: the first move is monitored (else the start is the robot's, unknown)
    return axes, dec, style, sep, eol, off


def _write_rapid(nom, axes, dec, style, sep, eol, off):
    cmap = controller_map(nom, "abb")
    from kincal.compensation.configuration import Configurator
    from kincal.compensation.programs.rapid import matrix_to_quat

    decl, moves = [], []
    for i, a in enumerate(axes):
        T = np.linalg.inv(WOBJ) @ nom.fk(cmap.to_model(a)) @ TOOL
        q = matrix_to_quat(T[:3, :3])
        sg = Configurator.of(nom, cmap).signs(cmap.to_model(a)[None])[0]   # ABB cfx bits
        cf = [int(np.floor(a[k] / 90.0)) for k in (0, 3, 5)] + \
            [4 * int(sg[0] < 0) + 2 * int(sg[1] < 0) + int(sg[2] < 0)]
        num = [_fmt(v * 1e3, dec, style) for v in T[:3, 3]]
        qq = [_fmt(v, dec + 4, style) for v in q]
        conf = [0, 0, 0, 0] if off[i] else cf
        decl.append(f"  CONST robtarget p{i}:=[[{sep.join(num)}],{eol}    [{sep.join(qq)}],"
                    f"[{sep.join(map(str, conf))}],[9E9,9E9,9E9,9E9,9E9,9E9]]; ! target {i}")
        moves.append(("    ConfL \\Off;" if off[i] else "    ConfL \\On;") + eol +
                     f"    MoveL p{i}, v100, fine, tGun\\WObj:=wFixture;")
    main = eol.join(["MODULE Gen", *decl, "  PROC main()", *moves, "  ENDPROC", "ENDMODULE", ""])
    return main.encode("latin-1")


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(_rapid_modules())
def test_generated_rapid_programs_round_trip_and_reach_their_targets(tmp_path_factory, robots,
                                                                     prog):
    nom, cal, cal_path = robots["irb120"]
    axes, dec, style, sep, eol, off = prog
    folder = tmp_path_factory.mktemp("gen")
    (folder / "Gen.mod").write_bytes(_write_rapid(nom, axes, dec, style, sep, eol, off))
    shutil.copy(TASK / "PROGMOD/CalibData.mod", folder / "CalibData.mod")
    from kincal.compensation.programs.driver import filter_program

    same = filter_program(str(folder), nom, nom)
    assert {Path(f).name: t for f, t in same.texts.items()} == \
        {Path(f).name: t for f, t in same.originals.items()}
    res = filter_program(str(folder), cal, nom)
    assert not res.failed, [r.reason for r in res.failed]
    f = next(k for k in res.texts if k.endswith("Gen.mod"))
    old, new = res.originals[f], res.texts[f]
    for a, b in zip(old.split("\n"), new.split("\n"), strict=True):
        if a != b:
            assert re.sub(r"[-+.\dE ]", "", a) == re.sub(r"[-+.\dE ]", "", b), (a, b)
    # read back: the calibrated robot on the written target's branch reaches the original
    cmap = controller_map(nom, "abb")
    def flat(text):
        return re.sub(r"\s*([,\[\]])\s*", r"\1", text)

    got, want = _robtargets(flat(new)), _robtargets(flat(old))
    prev = None
    res_pos = 0.5 * 10.0 ** -dec * 1e-3 * math.sqrt(3) * (1e2 if style == "exp" else 1)
    for i, a in enumerate(axes):
        pos, q, cf = got[f"p{i}"]
        cands = cmap.to_axes(_branches(nom, WOBJ @ _quat(pos, q) @ np.linalg.inv(TOOL)))
        if off[i] and prev is not None:
            best = _nearest_axes(cands, prev)
        else:
            cands = cands[np.all(np.floor(cands[:, [0, 3, 5]] / 90.0) == cf[:3], axis=1)]
            best = cands[np.argmin(np.abs(cands - a).max(axis=1))]
        tcp = cal.fk(cmap.to_model(best)) @ TOOL
        goal = WOBJ @ _quat(*want[f"p{i}"][:2])
        assert np.linalg.norm(tcp[:3, 3] - goal[:3, 3]) < 2 * res_pos + 2e-6, i
        prev = best
