"""Robot programs through the calibrated model: KRL, RAPID, URScript, FANUC .ls.

Checks: byte-identical round trips (robot = nominal), filtered targets equal to
`kincal compensate --filtered` on the same flange targets, orientation conventions
against closed forms, number formats (hypothesis), configurations (S/T, confdata,
CONFIG) picking the asked branch, and one-line errors with file:line:column.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run
from hypothesis import given, settings
from hypothesis import strategies as st

from kincal.compensation.configuration import Configurator, kuka_configuration
from kincal.compensation.filter import TargetRequest, filter_targets
from kincal.compensation.programs import fanuc, krl, rapid, urscript
from kincal.compensation.programs.base import read_frames
from kincal.compensation.programs.driver import filter_program, read_program
from kincal.compensation.programs.numbers import format_number, style_of
from kincal.errors import KincalError
from kincal.measure.simulate import perturb_robot
from kincal.motion.ik_wrist import ik_spherical_wrist
from kincal.robots.controller import controller_map
from kincal.robots.files import load_serial_robot, write_robot_yaml
from kincal.spatial import inverse, log_so3, rotx, roty, rotz

DATA = Path(__file__).parent / "data" / "programs"

#: (dialect, robot, program, frames file, written decimals: position [mm], angle [deg])
CASES = [
    ("krl", "kr6", "weld_seam.src", "krl_frames.yaml"),
    ("rapid", "irb120", "pick_place.mod", None),
    ("urscript", "ur5", "pick_and_place.script", None),
    ("fanuc-ls", "m10ia", "deburr.ls", "fanuc_frames.yaml"),
]
IDS = [c[0] for c in CASES]


def _copy(tmp_path: Path, program: str) -> Path:
    for f in DATA.iterdir():
        if f.stem == Path(program).stem or f.suffix == ".yaml":
            shutil.copy(f, tmp_path / f.name)
    return tmp_path / program


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """Each robot with 1 mm / 0.05 deg errors, written as a robot file."""
    folder = tmp_path_factory.mktemp("robots")
    out = {}
    for _, name, _, _ in CASES:
        nom = load_serial_robot(name)
        cal = perturb_robot(nom, np.random.default_rng(7)).with_name(f"{name}_cal")
        path = folder / f"{name}_cal.yaml"
        write_robot_yaml(cal, path)
        out[name] = (nom, load_serial_robot(str(path)), str(path))
    return out


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_filtering_with_the_nominal_robot_returns_the_file_byte_for_byte(case, tmp_path,
                                                                         capsys):
    dialect, robot, program, frames = case
    src = _copy(tmp_path, program)
    args = ["filter", src, "--robot", robot, "--nominal", robot, "-o", tmp_path / "out" / program]
    if frames:
        args += ["--frames", tmp_path / frames]
    code, out, err = run(capsys, *args)
    assert code == 0, err
    for f in (tmp_path / "out").iterdir():
        assert f.read_bytes() == (tmp_path / f.name).read_bytes(), f.name
    assert "0 not filtered" in out


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_only_the_numbers_of_changed_targets_change(case, tmp_path, calibrated, capsys):
    dialect, robot, program, frames = case
    src = _copy(tmp_path, program)
    out = tmp_path / "out" / program
    args = ["filter", src, "--robot", calibrated[robot][2], "--nominal", robot, "-o", out,
            "--json", tmp_path / "f.json"]
    if frames:
        args += ["--frames", tmp_path / frames]
    code, _, err = run(capsys, *args)
    assert code == 0, err
    doc = json.loads((tmp_path / "f.json").read_text())
    assert doc["program"] == str(src) and doc["nominal"] == robot and doc["robot"]
    assert doc["outputs"] and all(Path(o).parent == out.parent for o in doc["outputs"])
    assert doc["dialect"] == dialect and len(doc["targets"]) >= 1
    for f in (tmp_path / "out").iterdir():
        old, new = (tmp_path / f.name).read_bytes(), f.read_bytes()
        assert old.count(b"\r\n") == new.count(b"\r\n") and old.count(b"\n") == new.count(b"\n")
        old_l, new_l = old.split(b"\n"), new.split(b"\n")
        for a, b in zip(old_l, new_l, strict=True):
            if a != b:     # a changed line differs only inside numbers
                strip = bytes.maketrans(b"", b"")
                na = b"".join(ch for ch in (a.translate(strip, b"0123456789.-+eE "),))
                nb = b"".join(ch for ch in (b.translate(strip, b"0123456789.-+eE "),))
                assert na == nb, (a, b)


def _flange_targets(dialect, path, frames, robot_name):
    """Every filterable Cartesian target's flange pose and the reader's objects."""
    _, prog = read_program(str(path), dialect)
    fr = read_frames(str(frames)) if frames else None
    from kincal.compensation.programs.driver import _ops

    ops = _ops(dialect)
    out = []
    for t in prog.targets:
        if t.kind != "pose" or t.note or not t.used:
            continue
        user, tool = ops.frames(prog, t, fr or read_frames(None))
        out.append((t, user @ ops.pose_of(t) @ inverse(tool)))
    return out


#: What the written numbers resolve: (position [m], rotation [rad]); a tenth of the test's
#: bound (pick_place.mod writes mm with 2 decimals and quaternions with 7: the filter
#: writes no finer than the file).
RESOLUTION = {"krl": (1e-7, 1e-6), "rapid": (1e-6, 5e-8), "urscript": (1e-7, 1e-7),
              "fanuc-ls": (1e-6, 2e-5)}


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_filtered_targets_equal_kincal_compensate_filtered(case, tmp_path, calibrated, capsys):
    """The rewritten numbers, read back, are `kincal compensate --filtered` of the same flange
    targets seeded with the nominal solution on the program's configuration."""
    dialect, robot, program, frames = case
    nom, cal, cal_path = calibrated[robot]
    src = _copy(tmp_path, program)
    fr = tmp_path / frames if frames else None
    res = filter_program(str(src), cal, nom, dialect, read_frames(str(fr) if fr else None))
    targets = _flange_targets(dialect, src, fr, robot)
    reports = {(r.name, r.line): r for r in res.reports}
    assert all(reports[(t.name, t.line)].status == "filtered" for t, _ in targets)
    # the same targets through `kincal compensate`, seeded like the filter's nominal solutions
    rows_f = [r for r in res.reports if r.kind == "pose" and r.status == "filtered"]
    q_seed = res.result.q_nominal[[r.index for r in rows_f]]
    assert len(rows_f) == len(targets)
    names = list(nom.joint_names)
    with open(tmp_path / "t.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"]
                   + [f"{n}_rad" for n in names])
        from kincal.spatial import matrix_to_rpy

        for (_, F), q in zip(targets, q_seed, strict=True):
            w.writerow([repr(float(v)) for v in F[:3, 3]]
                       + [repr(float(v)) for v in matrix_to_rpy(F[:3, :3])]
                       + [repr(float(v)) for v in q])
    code, _, err = run(capsys, "compensate", cal_path, "--targets", tmp_path / "t.csv",
                       "--nominal", robot, "-o", tmp_path / "j.csv",
                       "--filtered", tmp_path / "f.csv")
    assert code == 0, err
    rows = [r for r in csv.reader(open(tmp_path / "f.csv")) if r and not r[0].startswith("#")]
    from kincal.spatial import xyzrpy_to_matrix

    expected = [xyzrpy_to_matrix(np.array([float(v) for v in r])) for r in rows[1:]]
    # read the filtered program back with the same reader
    out = tmp_path / "out" / program
    out.parent.mkdir()
    for f, text in res.texts.items():
        (out.parent / Path(f).name).write_bytes(text.encode("latin-1"))
    back = _flange_targets(dialect, out, fr, robot)
    dp, dr = RESOLUTION[dialect]
    for (t, F), E in zip(back, expected, strict=True):
        assert np.linalg.norm(F[:3, 3] - E[:3, 3]) < 10 * dp, t.name
        assert np.linalg.norm(log_so3(F[:3, :3] @ E[:3, :3].T)) < 10 * dr, t.name


# --------------------------------------------------------------------------- conventions
def _target(slots: dict[str, float], kind: str = "pose"):
    from kincal.compensation.programs.base import ProgramTarget, Slot

    return ProgramTarget("t", "f", 1, 1, kind, {k: Slot(0, 0, repr(v), v)
                                                 for k, v in slots.items()})


def test_orientation_conventions_against_closed_forms():
    d = math.radians
    a, b, c = 30.0, -20.0, 75.0
    T = krl.pose_of(_target(dict(x=1, y=2, z=3, a=a, b=b, c=c)))      # KUKA Z-Y'-X''
    assert np.allclose(T[:3, :3], rotz(d(a)) @ roty(d(b)) @ rotx(d(c)), atol=1e-15)
    assert np.allclose(T[:3, 3], [1e-3, 2e-3, 3e-3])
    T = fanuc.pose_of(_target(dict(x=0, y=0, z=0, w=c, p=b, r=a)))     # FANUC fixed X-Y-Z
    assert np.allclose(T[:3, :3], rotz(d(a)) @ roty(d(b)) @ rotx(d(c)), atol=1e-15)
    h = math.sqrt(0.5)                                                  # ABB q1 = w
    T = rapid.pose_of(_target(dict(x=0, y=0, z=0, q1=h, q2=0, q3=0, q4=h)))
    assert np.allclose(T[:3, :3], rotz(math.pi / 2), atol=1e-15)
    T = rapid.pose_of(_target(dict(x=0, y=0, z=0, q1=0, q2=1, q3=0, q4=0)))
    assert np.allclose(T[:3, :3], rotx(math.pi), atol=1e-15)
    T = urscript.pose_of(_target(dict(x=0, y=0, z=0, rx=0, ry=math.pi / 2, rz=0)))  # UR
    assert np.allclose(T[:3, :3], roty(math.pi / 2), atol=1e-15)
    # writing back gives the same numbers (angles near the old ones)
    t = _target(dict(x=1, y=2, z=3, a=179.5, b=10, c=-179.0))
    v = krl.pose_values(t, krl.pose_of(t))
    assert np.allclose([v[k] for k in "xyzabc"], [1, 2, 3, 179.5, 10, -179.0])
    t = _target(dict(x=0, y=0, z=0, q1=-h, q2=0, q3=0, q4=-h))
    v = rapid.pose_values(t, rapid.pose_of(t))
    assert np.allclose([v[k] for k in ("q1", "q2", "q3", "q4")], [-h, 0, 0, -h])


@settings(max_examples=300, deadline=None)
@given(sign=st.sampled_from(["", "-", "+"]), whole=st.integers(0, 99999),
       frac=st.text("0123456789", min_size=0, max_size=7),
       lead=st.booleans(), exp=st.sampled_from(["", "e", "E"]),
       exp_sign=st.sampled_from(["", "+", "-"]), exp_digits=st.integers(1, 3),
       value=st.floats(-1e4, 1e4, allow_nan=False))
def test_number_formats_round_trip(sign, whole, frac, lead, exp, exp_sign, exp_digits, value):
    mant = (str(whole) if lead or whole else "") + ("." + frac if frac or not lead else "")
    if mant in ("", "."):
        mant = "0"
    text = sign + mant + (exp + exp_sign + "0" * (exp_digits - 1) + "2" if exp else "")
    style = style_of(text)
    assert format_number(float(text), style) == text or float(
        format_number(float(text), style)) == float(text)
    new = format_number(value, style, 4)
    assert style_of(new).exp == style.exp
    assert style_of(new).plus == (style.plus and new[0] == "+")
    tol = 0.5 * 10 ** -4 if exp else 0.5 * 10 ** -max(style.decimals, 4)
    assert abs(float(new) - value) <= tol * 1.000001


# --------------------------------------------------------------------------- branches
def test_kuka_status_and_turn_choose_the_branch():
    """All 8 solutions of one pose: the S/T of each picks exactly that solution."""
    nom = load_serial_robot("kr6")
    cmap = controller_map(nom)
    conf = Configurator.of(nom, cmap)
    q0 = np.radians([10, -70, 100, 30, 40, -20])
    sol = ik_spherical_wrist(nom, nom.fk(q0[None]))
    ok = sol.within_limits[0]
    assert ok.sum() >= 2
    for b in np.flatnonzero(ok):
        q = sol.q[0, b]
        s = conf.signs(q[None])[0]
        S = int((s[0] < 0) + 2 * (s[1] > 0) + 4 * (s[2] < 0))
        T = int(sum((np.degrees(q[k]) < 0) << k for k in range(6)))
        picked, found = conf.select(sol.q, sol.reachable, [kuka_configuration(S, T)])
        assert found[0] and np.allclose(picked[0], q)
    # HOME is S 2 (basic area, elbow as at HOME, A5 >= 0)
    home = np.radians([0, -90, 90, 0, 30, 0])
    assert tuple(conf.signs(home[None])[0]) == (1, 1, 1)


def test_singularity_warnings_name_the_right_targets_after_a_branch_is_refused():
    """A calibrated A5 offset of +1 deg: the target at A5 = 0.5 deg flips the wrist (its
    configuration is refused), the one at 1.5 deg lands at 0.5 deg (near the wrist
    singularity), the one at 40 deg is far from every singularity."""
    nom = load_serial_robot("kr6")
    cal = nom.with_params({"theta_offset[5]": nom.params()["theta_offset[5]"]
                           + math.radians(1.0)})
    conf = Configurator.of(nom, controller_map(nom))
    q = np.array([[0.3, -1.2, 1.4, 0.4, math.radians(0.5), 0.2],
                  [0.1, -1.4, 1.6, -0.3, math.radians(1.5), 0.5],
                  [-0.2, -1.3, 1.2, 0.3, math.radians(40.0), -0.4]])
    requests = []
    for F, s in zip(nom.fk(q), conf.signs(q), strict=True):
        S = int((s[0] < 0) + 2 * (s[1] > 0) + 4 * (s[2] < 0))
        requests.append(TargetRequest("pose", flange=F, config=kuka_configuration(S, None)))
    res = filter_targets(cal, nom, requests)
    assert list(res.ok) == [False, True, True]
    assert "another branch" in res.reason[0]
    assert res.warnings[1] == ["near a singularity"]
    assert res.warnings[2] == []


def test_reference_poses_of_the_built_in_robots():
    """Published geometry: flange positions at the vendors' reference postures [mm]."""
    cases = [("kr6", [0, -90, 90, 0, 0, 0], [525.0, 0.0, 890.0]),       # KR 6 R900 HOME
             ("irb120", [0, 0, 0, 0, 0, 0], [374.0, 0.0, 630.0]),       # IRB 120 calibration
             ("m10ia", [0, 0, 0, 0, 0, 0], [890.0, 0.0, 800.0])]        # M-10iA zero
    for name, axes, p in cases:
        r = load_serial_robot(name)
        q = controller_map(r).to_model(np.array(axes, float))
        assert np.allclose(r.fk(q)[:3, 3] * 1e3, p, atol=1e-9), name
    ur = load_serial_robot("ur5")                    # UR5 zero: arm stretched along -x
    assert np.allclose(ur.fk(np.zeros(6))[:3, 3] * 1e3, [-817.25, -191.45, -5.491], atol=1e-9)


def test_fanuc_j2_j3_coupling_matches_a_urdf_style_chain():
    """The M-10iA's DH model with q3 = -(J2 + J3) equals a chain built like ROS-Industrial's
    URDF (joint_3 = J2 + J3, axes +z, +y, -y, -x, -y, -x) at random axis values."""
    from kincal.robots.chain import ChainBuilder

    b = ChainBuilder("urdf_style")
    b.frame("base", [0, 0, -0.45, 0, 0, 0])
    j = [b.joint(f"j{i}", "revolute") for i in range(6)]
    for (x, y, z), (axis, s), k in zip([(0, 0, 0.45), (0.15, 0, 0), (0, 0, 0.6), (0, 0, 0.2),
                                        (0.64, 0, 0), (0.1, 0, 0)],
                                       [("Rz", 1), ("Ry", 1), ("Ry", -1), ("Rx", -1), ("Ry", -1),
                                        ("Rx", -1)], j, strict=True):
        for kind, v in zip(("Tx", "Ty", "Tz"), (x, y, z), strict=True):
            b.transform(kind, None, v)
        b.transform(axis, None, 0.0, joint=k, scale=s)
    b.transform("Ry", None, -math.pi / 2)
    b.transform("Rx", None, math.pi)
    b.frame("tool")
    ref = b.build()
    m = load_serial_robot("m10ia")
    J = np.random.default_rng(0).uniform(-1.5, 1.5, (50, 6))
    Jr = J.copy()
    Jr[:, 2] = J[:, 1] + J[:, 2]
    assert np.abs(ref.fk(Jr) - m.fk(controller_map(m).to_model(np.degrees(J)))).max() < 1e-14


# --------------------------------------------------------------------------- errors
BAD = [
    ("weld_seam.dat", "X 405.5,Y -85.2", "X 405.5,Y -8x5.2", "weld_seam.src", 7, "item Y"),
    ("pick_place.mod", "[259.03,78.27,335.36]", "[259.03,78.27]", "pick_place.mod", 11,
     "robtarget position"),
    ("pick_and_place.script", "p[-0.61606, -0.1717,", "p[-0.61606, -0.17q17,",
     "pick_and_place.script", 5, "pose"),
    ("deburr.ls", "Y =  -152.307  mm", "Y =  -152.3.07  mm", "deburr.ls", 23, "Y"),
]


@pytest.mark.parametrize("bad", BAD, ids=IDS)
def test_bad_content_gives_one_line_with_file_line_column_and_writes_nothing(bad, tmp_path,
                                                                             capsys):
    edit, old, new, program, line, what = bad
    src = _copy(tmp_path, program)
    f = tmp_path / edit
    f.write_bytes(f.read_bytes().replace(old.encode(), new.encode(), 1))
    robot = {"weld_seam.src": "kr6", "pick_place.mod": "irb120",
             "pick_and_place.script": "ur5", "deburr.ls": "m10ia"}[program]
    args = ["filter", src, "--robot", robot, "--nominal", robot, "-o", tmp_path / "o" / program]
    frames = {"weld_seam.src": "krl_frames.yaml", "deburr.ls": "fanuc_frames.yaml"}.get(program)
    if frames:
        args += ["--frames", tmp_path / frames]
    code, out, err = run(capsys, *args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"{edit}:{line}:" in lines[0] and what in lines[0], err
    assert not (tmp_path / "o").exists()


def test_a_report_file_that_is_an_input_is_refused_before_anything_is_written(tmp_path,
                                                                              capsys):
    """--csv / --json on the program or the frames file: exit 2, one line, inputs intact."""
    src = _copy(tmp_path, "weld_seam.src")
    frames = tmp_path / "krl_frames.yaml"
    before = src.read_bytes(), frames.read_bytes()
    for opt, victim in (("--csv", src), ("--json", frames)):
        code, _, err = run(capsys, "filter", src, "--robot", "kr6", "--nominal", "kr6",
                           "--frames", frames, "-o", tmp_path / "o" / "out.src", opt, victim)
        assert code == 2 and f"option {opt}:" in err and "also the input of" in err, err
    assert (src.read_bytes(), frames.read_bytes()) == before
    assert not (tmp_path / "o").exists()


def test_krl_module_names_follow_the_new_file_name(tmp_path, calibrated, capsys):
    """The controller requires DEF name( of a .src and DEFDAT name of its .dat to match the
    file name: -o seam_cal.src renames both (and nothing else: the bytes are the filtered
    program's but for those two names); a file name that is no KRL name writes nothing."""
    _, _, cal_path = calibrated["kr6"]
    src = _copy(tmp_path, "weld_seam.src")
    (tmp_path / "o").mkdir()
    same, new = tmp_path / "o" / "weld_seam.src", tmp_path / "o" / "seam_cal.src"
    base = ["filter", src, "--robot", cal_path, "--nominal", "kr6", "--frames",
            tmp_path / "krl_frames.yaml", "-o"]
    assert run(capsys, *base, same)[0] == 0
    assert run(capsys, *base, new)[0] == 0
    for suffix, head in ((".src", b"DEF "), (".dat", b"DEFDAT  ")):
        a, b = same.with_suffix(suffix).read_bytes(), new.with_suffix(suffix).read_bytes()
        assert head + b"weld_seam" in a and head + b"weld_seam" not in b
        assert b.replace(head + b"seam_cal", head + b"weld_seam") == a
        assert b"\r\n" in b and b.count(b"\r\n") == a.count(b"\r\n")
    code, _, err = run(capsys, *base, tmp_path / "o" / "9-seam.src")
    assert code == 2 and "'9-seam' is not a KRL module name" in err
    assert not (tmp_path / "o" / "9-seam.src").exists()


def test_an_unreachable_target_is_left_unchanged_listed_and_exits_1(tmp_path, capsys):
    src = _copy(tmp_path, "pick_and_place.script")
    text = src.read_text()
    src.write_text(text.replace("p[-0.55412, 0.06426, 0.16272,", "p[-1.55412, 0.06426, 0.16272,"))
    out = tmp_path / "o.script"
    code, stdout, err = run(capsys, "filter", src, "--robot", "ur5", "--nominal", "ur5", "-o", out)
    assert code == 1
    assert "1 of 5 targets could not be filtered" in err and "line 9" in err
    assert out.read_bytes() == src.read_bytes()


def test_joint_targets_offline_are_corrected_taught_ones_stay(tmp_path, calibrated, capsys):
    nom, cal, cal_path = calibrated["ur5"]
    src = _copy(tmp_path, "pick_and_place.script")
    taught = filter_program(str(src), cal, nom)
    offline = filter_program(str(src), cal, nom, offline_joints=True)
    kinds = [(r.kind, r.status) for r in taught.reports]
    assert ("joints", "kept") in kinds
    assert [r.status for r in offline.reports if r.kind == "joints"] == ["filtered", "filtered"]
    # the corrected joints put the calibrated robot where the nominal one was sent
    _, back = read_program(str(src), "urscript")
    q_in = [t.values(urscript.JOINT_KEYS) for t in back.targets if t.kind == "joints"]
    out = tmp_path / "o.script"
    out.write_bytes(offline.texts[str(src)].encode("latin-1"))
    _, newp = read_program(str(out), "urscript")
    q_out = [t.values(urscript.JOINT_KEYS) for t in newp.targets if t.kind == "joints"]
    for a, b in zip(q_in, q_out, strict=True):
        assert np.linalg.norm(cal.fk(b)[:3, 3] - nom.fk(a)[:3, 3]) < 1e-6


# --------------------------------------------------------------------------- plan --program
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_plan_writes_a_joint_move_program_the_readers_read_back(case, tmp_path, capsys):
    dialect, robot, _, _ = case
    from kincal.compensation.programs.writers import SUFFIX

    out = tmp_path / f"poses{SUFFIX[dialect]}"
    code, stdout, err = run(capsys, "plan", robot, "-n", "12", "--candidates", "200",
                            "--program", dialect, "-o", out, "--dwell", "1.5s",
                            "--angle-unit", "rad")
    assert code == 0, err
    rows = [r for r in csv.reader(open(tmp_path / "poses.csv")) if r and not r[0].startswith("#")]
    q_plan = np.array([[float(v) for v in r] for r in rows[1:]])
    _, prog = read_program(str(out), dialect)
    from kincal.compensation.programs.driver import _ops

    keys = _ops(dialect).joint_keys
    nom = load_serial_robot(robot)
    q_read = np.array([controller_map(nom, "ur" if dialect == "urscript" else None)
                       .to_model(t.values(keys)) for t in prog.targets])
    digits = {"krl": 4, "rapid": 4, "urscript": 6, "fanuc-ls": 3}[dialect]
    scale = 1.0 if dialect == "urscript" else math.pi / 180
    assert q_read.shape == q_plan.shape
    assert np.abs(q_read - q_plan).max() <= 0.5 * 10 ** -digits * scale * 1.01 * 2


def test_predicted_accuracy_and_the_calibrated_region(tmp_path):
    """With a calibration's accuracy model (kincal.identify.accuracy), each filtered target
    gets the predicted position std of the calibrated model at its TCP, and targets whose
    joints leave the training ranges are flagged 'outside the calibrated region'."""
    from kincal.compensation.filter import tcp_accuracy
    from kincal.identify.accuracy import AccuracyModel, accuracy_model, predicted_position_std
    from kincal.identify.solver import calibrate
    from kincal.measure.instruments.position import simulate_positions

    nom = load_serial_robot("ur5")
    truth = perturb_robot(nom, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    q = rng.uniform(-0.6, 0.6, (40, 6)) + np.array([0.1, -1.2, 1.5, -1.9, -1.57, 0.3])
    res = calibrate(nom, [simulate_positions(truth, q, rng, noise_std=1e-5)])
    model = accuracy_model(res)
    src = _copy(tmp_path, "pick_and_place.script")
    out = filter_program(str(src), res.robot, nom, accuracy=model)
    poses = [r for r in out.reports if r.kind == "pose"]
    assert all(np.isfinite(r.predicted_std_mm) and r.predicted_std_mm > 0 for r in poses)
    # the std at the program's TCP is the covariance propagated to that point, and the
    # result JSON's model (to_dict / from_dict) gives the same numbers
    q_t = np.array([out.result.joints[r.index] for r in poses])
    m = np.array([0.0, 0.0, 0.15])                                  # the program's set_tcp
    assert np.allclose(predicted_position_std(res, q_t, point=m) * 1e3,
                       [r.predicted_std_mm for r in poses], rtol=1e-9)
    back = AccuracyModel.from_dict(json.loads(json.dumps(model.to_dict())))
    std, outside = tcp_accuracy(back, res.robot, q_t, np.tile(m, (len(q_t), 1)))
    assert np.allclose(std * 1e3, [r.predicted_std_mm for r in poses], rtol=1e-9)
    # a far target (shoulder pan turned by 2 rad) is outside the region the data covered
    text = src.read_text().replace("movej(home, a=1.4, v=1.05)",
                                   "movej([2.5, -1.2, 1.5, -1.9, -1.57, 0.3])\n"
                                   "  movel(p[0.5, 0.3, 0.2, 0.0, 3.14, 0.0])")
    src.write_text(text)
    out = filter_program(str(src), res.robot, nom, accuracy=model)
    flagged = [r for r in out.reports if "outside the calibrated region" in r.warnings]
    assert flagged and all(r.kind == "pose" for r in flagged)


def test_filter_reads_the_older_accuracy_model(tmp_path):
    """A result JSON whose accuracy_model holds only the robot parameters' covariance and
    the training joint ranges (what `kincal calibrate --json` wrote before the hull, the
    measured point and the floor were added) still gives the std at each TCP and the
    joint-range flag."""
    from kincal.compensation.filter import tcp_accuracy
    from kincal.identify.accuracy import AccuracyModel, predicted_position_std
    from kincal.identify.solver import calibrate
    from kincal.measure.instruments.position import simulate_positions

    nom = load_serial_robot("ur5")
    truth = perturb_robot(nom, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    q = rng.uniform(-0.6, 0.6, (40, 6)) + np.array([0.1, -1.2, 1.5, -1.9, -1.57, 0.3])
    res = calibrate(nom, [simulate_positions(truth, q, rng, noise_std=1e-5)])
    keep = [i for i, n in enumerate(res.estimated) if n in nom.param_names]
    old = {"parameters": [res.estimated[i] for i in keep],
           "covariance": res.covariance[np.ix_(keep, keep)].tolist(),
           "joint_names": list(nom.joint_names), "joint_min": q.min(axis=0).tolist(),
           "joint_max": q.max(axis=0).tolist(), "note": "covariance (m, rad)"}
    model = AccuracyModel.from_dict(old)
    m = np.array([0.01, 0.0, 0.15])
    q_t = np.vstack([q[:5], q[0] + [2.0, 0, 0, 0, 0, 0]])
    std, outside = tcp_accuracy(model, res.robot, q_t, np.tile(m, (len(q_t), 1)))
    assert np.allclose(std, predicted_position_std(res, q_t, point=m), rtol=1e-9)
    assert outside.tolist() == [False] * 5 + [True]
    rj = tmp_path / "old.json"
    rj.write_text(json.dumps({"accuracy_model": old}))
    from kincal.workflow.flow import accuracy_from_result

    assert accuracy_from_result(rj, res.robot).parameters == tuple(old["parameters"])
    with pytest.raises(KincalError, match="for another robot"):
        accuracy_from_result(rj, load_serial_robot("puma560"))


def test_filter_result_json_gives_predicted_accuracy_per_target(tmp_path, capsys):
    """`kincal calibrate --json` stores the robot parameters' covariance and the training
    joint ranges; `kincal filter --result` reports the predicted std at every target's TCP,
    equal to the in-memory propagation (kincal.identify.accuracy), and flags targets
    outside the calibrated joint ranges."""
    from kincal.compensation.filter import tcp_accuracy
    from kincal.workflow.flow import accuracy_from_result

    train = tmp_path / "train.csv"
    code, _, err = run(capsys, "simulate", "kr6", "-o", train, "--truth", tmp_path / "t.yaml",
                       "--poses", "60", "--noise", "0.01mm", "--seed", "1")
    assert code == 0, err
    cal, rj = tmp_path / "cal.yaml", tmp_path / "r.json"
    code, _, err = run(capsys, "calibrate", "kr6", "--data", train, "-o", cal, "--json", rj)
    assert code == 0, err
    src = _copy(tmp_path, "weld_seam.src")
    code, out, err = run(capsys, "filter", src, "--robot", cal, "--nominal", "kr6", "-o",
                         tmp_path / "o" / "weld_seam.src", "--frames",
                         tmp_path / "krl_frames.yaml", "--result", rj, "--json",
                         tmp_path / "f.json")
    assert code == 0, err
    rows = json.loads((tmp_path / "f.json").read_text())["targets"]
    stds = [r["predicted_std_mm"] for r in rows if r["status"] == "filtered"]
    assert stds and all(s > 0 for s in stds)
    model = accuracy_from_result(rj, load_serial_robot(str(cal)))
    std, outside = tcp_accuracy(model, load_serial_robot(str(cal)),
                                np.radians([[5.0, -80, 100, 10, 40, -20]]),
                                np.array([[0.01, 0, 0.15]]))
    assert std[0] > 0
