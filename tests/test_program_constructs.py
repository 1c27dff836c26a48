"""Robot programs as real cells write them: KSS 8 inline forms and spline blocks, any
.dat item, partial aggregates, URScript values in program order, PolyScope exports,
values computed at run time, programs with nothing to filter.

The corpus (tests/data/programs/) is written from the vendors' documented syntax.  The
controller's meaning of each target is computed here independently of the filter: the
frames named by the motion (KSS: ``STOOL2(FP1)`` = ``TOOL_DATA[FP1.TOOL_NO]``,
``SBASE(FP1.BASE_NO)`` = ``BASE_DATA[FP1.BASE_NO]``), composed with numpy as
``F = BASE * pose * TOOL^-1``, the left-out components of a partial aggregate taken from
the previous position, a URScript variable's value the one assigned last before its use;
then the nominal controller's joints for the filtered target (closed form / numerical
IK of the nominal robot) must put the calibrated robot on the original target.
"""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import run
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kincal.compensation.programs.base import read_frames
from kincal.compensation.programs.driver import filter_program, read_program
from kincal.compensation.programs.numbers import NUMBER
from kincal.measure.simulate import perturb_robot
from kincal.motion.ik import solve_ik
from kincal.motion.ik_wrist import ik_spherical_wrist
from kincal.robots.controller import controller_map
from kincal.robots.files import load_serial_robot, write_robot_yaml
from kincal.spatial import log_so3

DATA = Path(__file__).parent / "data" / "programs"
#: (dialect, robot, program, frames file): every program of the corpus.
CORPUS = [
    ("krl", "kr6", "weld_seam.src", "krl_frames.yaml"),
    ("krl", "kr6", "spline_cell.src", "spline_frames.yaml"),
    ("krl", "kr6", "hand_moves.src", "krl_frames.yaml"),
    ("krl", "kr6", "Go_Home.src", None),
    ("krl", "kr6", "rsi_driver.src", None),
    ("krl", "kr6", "eki_driver.src", None),
    ("urscript", "ur5", "pick_and_place.script", None),
    ("urscript", "ur5", "reassign.script", None),
    ("urscript", "ur5", "polyscope_export.script", None),
    ("urscript", "ur5", "external_control.script", None),
]
IDS = [c[2] for c in CORPUS]
#: What the written numbers resolve (4 decimals of mm / deg; 7 of m / rad), as a bound
#: on the pose error they leave [m, rad] at a 1 m lever.
TOL_P, TOL_R = 3e-6, 3e-6


def _copy(tmp_path: Path, program: str) -> Path:
    for f in DATA.iterdir():
        if f.stem == Path(program).stem or f.suffix == ".yaml":
            shutil.copy(f, tmp_path / f.name)
    return tmp_path / program


@pytest.fixture(scope="module")
def robots(tmp_path_factory):
    """Each robot and a calibrated one (mm-level errors), the latter also as a file."""
    folder = tmp_path_factory.mktemp("robots")
    out = {}
    for name in ("kr6", "ur5"):
        nom = load_serial_robot(name)
        cal = perturb_robot(nom, np.random.default_rng(7)).with_name(f"{name}_cal")
        write_robot_yaml(cal, folder / f"{name}_cal.yaml")
        out[name] = (nom, cal, str(folder / f"{name}_cal.yaml"))
    return out


# --------------------------------------------------------------------------- independent
def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def kuka(x, y, z, a, b, c) -> np.ndarray:
    """KUKA ``{X, Y, Z, A, B, C}`` [mm, deg] as a 4x4 [m]: ``R = Rz(A) Ry(B) Rx(C)``."""
    T = np.eye(4)
    T[:3, :3] = _rz(math.radians(a)) @ _ry(math.radians(b)) @ _rx(math.radians(c))
    T[:3, 3] = np.array([x, y, z]) * 1e-3
    return T


def ur_pose(v) -> np.ndarray:
    """``p[x, y, z, rx, ry, rz]`` as a 4x4 (Rodrigues' formula)."""
    r = np.asarray(v[3:], float)
    th = float(np.linalg.norm(r))
    K = np.zeros((3, 3))
    if th > 0:
        k = r / th
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    T[:3, 3] = v[:3]
    return T


def _frames_yaml(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """The frames file read with yaml, composed as KUKA frames (rz, ry, rx = A, B, C)."""
    doc = yaml.safe_load(path.read_text())
    return {w: {str(k): kuka(f["x"], f["y"], f["z"], f["rz"], f["ry"], f["rx"])
                for k, f in doc[w].items()} for w in ("tool", "base")}


def _agg(text: str) -> dict[str, float]:
    """``{X 1.0, Y 2.0, ...}`` -> numbers by key (numbers only)."""
    out = {}
    for item in text.strip("{}").split(","):
        k, _, v = item.strip().partition(" ")
        if re.fullmatch(r"[-+]?[\d.]+(?:E[-+]?\d+)?", v.strip(), re.I):
            out[k.upper()] = float(v)
    return out


def _dat_point(text: str, name: str) -> dict[str, float]:
    m = re.search(rf"^DECL \w+ {name}=(\{{[^\r\n]*\}})", text, re.M)
    assert m, name
    return _agg(m.group(1))


def _pose(d: dict[str, float]) -> np.ndarray:
    return kuka(*(d[k] for k in ("X", "Y", "Z", "A", "B", "C")))


def _distance(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    c = (np.trace(A[:3, :3] @ B[:3, :3].T) - 1) / 2
    return dp, float(math.acos(min(1.0, max(-1.0, c))))


def _reaches(nom, cal, F_sent: np.ndarray, F_meant: np.ndarray, near=None):
    """The nominal controller's joints for the flange pose it is sent (closed form, the
    branch nearest ``near`` or the best one) and how far the calibrated robot there is
    from the flange pose meant: ``(q, [m], [rad])`` (None, inf, inf where unreachable)."""
    sol = ik_spherical_wrist(nom, F_sent[None])
    best = None
    for b in np.flatnonzero(sol.reachable[0]):
        q = sol.q[0, b]
        d = _distance(cal.fk(q), F_meant)
        key = np.abs(q - near).max() if near is not None else d[0]
        if best is None or key < best[0]:
            best = (key, q, d)
    if best is None:
        return None, math.inf, math.inf
    return best[1], best[2][0], best[2][1]


# --------------------------------------------------------------------------- corpus
@pytest.mark.parametrize("case", CORPUS, ids=IDS)
def test_every_program_of_the_corpus_comes_back_byte_for_byte_with_the_nominal_robot(
        case, tmp_path, capsys):
    dialect, robot, program, frames = case
    src = _copy(tmp_path, program)
    args = ["filter", src, "--robot", robot, "--nominal", robot, "-o", tmp_path / "out" / program]
    if frames:
        args += ["--frames", tmp_path / frames]
    code, out, err = run(capsys, *args)
    assert code == 0, err
    outs = list((tmp_path / "out").iterdir())
    assert outs
    for f in outs:
        assert f.read_bytes() == (tmp_path / f.name).read_bytes(), f.name


def _slot_spans(prog, reports, statuses) -> dict[str, set[tuple[int, int]]]:
    spans: dict[str, set[tuple[int, int]]] = {}
    for t, r in zip(prog.targets, reports, strict=True):
        if r.status in statuses:
            for s in t.slots.values():
                spans.setdefault(t.file, set()).add((s.start, s.end))
    return spans


def assert_only_target_numbers_changed(path: str, dialect: str, res) -> None:
    """Every file has its lines; a changed line differs only in numbers, and each
    changed number is one of a filtered (or partial) target's slots."""
    _, prog = read_program(path, dialect)
    spans = _slot_spans(prog, res.reports, ("filtered", "partial"))
    for f, old in res.originals.items():
        new = res.texts[f]
        old_l, new_l = old.splitlines(keepends=True), new.splitlines(keepends=True)
        assert len(old_l) == len(new_l)
        pos = 0
        for a, b in zip(old_l, new_l, strict=True):
            if a != b:
                assert NUMBER.split(a) == NUMBER.split(b), (a, b)
                for ma, mb in zip(NUMBER.finditer(a), NUMBER.finditer(b), strict=True):
                    if ma.group() != mb.group():
                        assert (pos + ma.start(), pos + ma.end()) in spans.get(f, set()), a
            pos += len(a)


@pytest.mark.parametrize("case", CORPUS, ids=IDS)
def test_a_calibrated_filter_changes_only_target_numbers(case, tmp_path, robots):
    dialect, robot, program, frames = case
    nom, cal, _ = robots[robot]
    src = _copy(tmp_path, program)
    res = filter_program(str(src), cal, nom, dialect,
                         read_frames(str(tmp_path / frames) if frames else None))
    assert not res.failed, [(r.name, r.reason) for r in res.failed]
    assert_only_target_numbers_changed(str(src), dialect, res)


# --------------------------------------------------------------------------- KRL
#: spline_cell: the tool / base numbers of each target by the FDAT its motion names.
SPLINE_FRAMES = {**{f"XP{k}": ("2", "3") for k in (1, 2, 3, 4, 10, 11)},
                 **{f"XP{k}": ("1", "2") for k in (5, 6, 7, 8)}}


def test_kss8_inline_forms_and_spline_blocks_use_the_frames_their_motion_names(tmp_path,
                                                                                robots):
    """SPTP/SLIN/SCIRC ... WITH $TOOL = STOOL2(FPn), $BASE = SBASE(FPn.BASE_NO) and the
    segments of SPLINE / PTP_SPLINE blocks: the calibrated robot, at the nominal
    controller's joints for each filtered target, is on the taught target in the frames
    the motion names (tool 2 / base 3 while tool 1 / base 2 are active before); in the
    frames active before, it would not be."""
    nom, cal, _ = robots["kr6"]
    src = _copy(tmp_path, "spline_cell.src")
    fr = _frames_yaml(tmp_path / "spline_frames.yaml")
    res = filter_program(str(src), cal, nom, "krl",
                         read_frames(str(tmp_path / "spline_frames.yaml")))
    status = {r.name: r.status for r in res.reports}
    assert all(status[n] == "filtered" for n in SPLINE_FRAMES) and status["line 35"] == \
        "filtered"
    dat = str(tmp_path / "spline_cell.dat")
    old_dat, new_dat = res.originals[dat], res.texts[dat]
    old_src, new_src = res.originals[str(src)], res.texts[str(src)]
    inline = re.compile(r"^\s*SPL (\{[^}]*\})", re.M)
    cases = [(n, _dat_point(old_dat, n), _dat_point(new_dat, n), SPLINE_FRAMES[n])
             for n in SPLINE_FRAMES]
    cases.append(("line 35", _agg(inline.search(old_src).group(1)),
                  _agg(inline.search(new_src).group(1)), ("1", "2")))
    for name, old, new, (tool, base) in cases:
        B, T = fr["base"][base], fr["tool"][tool]
        meant = B @ _pose(old) @ np.linalg.inv(T)
        _, dp, dr = _reaches(nom, cal, B @ _pose(new) @ np.linalg.inv(T), meant)
        assert dp < TOL_P and dr < TOL_R, (name, dp, dr)
        if (tool, base) != ("1", "2"):        # the frames active before the motion
            B1, T1 = fr["base"]["2"], fr["tool"]["1"]
            _, dp, _ = _reaches(nom, cal, B1 @ _pose(new) @ np.linalg.inv(T1),
                                B1 @ _pose(old) @ np.linalg.inv(T1))
            assert dp > 1e-5, name


def test_tool_data_of_an_fdat_number_is_the_same_as_stool2(tmp_path, robots):
    """``$TOOL = TOOL_DATA[FP2.TOOL_NO]`` and ``$BASE = BASE_DATA[FP2.BASE_NO]`` in the WITH
    clause mean what STOOL2(FP2) / SBASE(FP2.BASE_NO) mean: the same filtered program."""
    nom, cal, _ = robots["kr6"]
    src = _copy(tmp_path, "spline_cell.src")
    fr = read_frames(str(tmp_path / "spline_frames.yaml"))
    before = filter_program(str(src), cal, nom, "krl", fr)
    text = src.read_bytes().replace(b"$TOOL = STOOL2(FP2), $BASE = SBASE(FP2.BASE_NO)",
                                    b"$TOOL = TOOL_DATA[FP2.TOOL_NO], $BASE = BASE_DATA["
                                    b"FP2.BASE_NO]")
    assert text != src.read_bytes()
    src.write_bytes(text)
    after = filter_program(str(src), cal, nom, "krl", fr)
    dat = str(tmp_path / "spline_cell.dat")
    assert after.texts[dat] == before.texts[dat]
    assert [r.status for r in after.reports] == [r.status for r in before.reports]


def test_dat_items_the_filter_does_not_need_never_stop_it(tmp_path, robots):
    """Booleans, enums, strings with commas, nested aggregates, other types (LDAT, PDAT,
    BOOL, CHAR) anywhere in the .dat, and such items inside FDAT and E6POS."""
    src = _copy(tmp_path, "weld_seam.src")
    dat = tmp_path / "weld_seam.dat"
    text = dat.read_bytes().decode("latin-1")
    text = text.replace("E6 0.0}\r\nDECL FDAT", 'E6 0.0}\r\nDECL BOOL B_OK=TRUE\r\nDECL FDAT', 1)
    text = text.replace('POINT2[] " "}', 'POINT2[] "a, b {c}",TQ_STATE FALSE,'
                        'CB {AUX_PT {ORI #CONSIDER,E1 #CONSIDER},TARGET_PT {ORI #INTERPOLATE}}}')
    text = text.replace("S 2,T 34,E1 0.0", "S 2,T 34,E1 #NONE,EXT {A 1,B FALSE}")
    dat.write_bytes(text.encode("latin-1"))
    nom, cal, _ = robots["kr6"]
    res = filter_program(str(src), cal, nom, "krl", read_frames(str(tmp_path /
                                                                     "krl_frames.yaml")))
    assert {r.name: r.status for r in res.reports}["XP1"] == "filtered"
    assert not res.failed


def _kuka_euler(R: np.ndarray) -> np.ndarray:
    """A, B, C [deg] of R = Rz(A) Ry(B) Rx(C) (away from B = +-90)."""
    return np.degrees([math.atan2(R[1, 0], R[0, 0]), math.asin(-R[2, 0]),
                       math.atan2(R[2, 1], R[2, 2])])


def test_partial_aggregates_take_the_previous_position_as_the_controller_does(tmp_path,
                                                                                robots):
    """hand_moves: PTP to axes, PTP {A1 15} (A2..A6 kept), then LIN aggregates without
    some of X Y Z A B C.  The meaning of each (the left-out components of the previous
    position, in base 2 / tool 1) is built here; the filtered program assembled the
    same way at run time puts the calibrated robot where the table says: on the full
    target, and at the reported distance from each partial one."""
    nom, cal, _ = robots["kr6"]
    src = _copy(tmp_path, "hand_moves.src")
    fr = _frames_yaml(tmp_path / "krl_frames.yaml")
    B, T = fr["base"]["2"], fr["tool"]["1"]
    res = filter_program(str(src), cal, nom, "krl",
                         read_frames(str(tmp_path / "krl_frames.yaml")))
    cmap = controller_map(nom)
    q10 = cmap.to_model(np.array([15.0, -80, 100, 20, 45, -30]))
    start = np.linalg.inv(B) @ nom.fk(q10) @ T
    start_vals = dict(zip("XYZ", start[:3, 3] * 1e3, strict=True)) | dict(
        zip("ABC", _kuka_euler(start[:3, :3]), strict=True))

    def follow(text: str) -> list[dict[str, float]]:
        """The full values of each LIN at run time, in program order."""
        prev, out = dict(start_vals), []
        for m in re.finditer(r"^LIN (\{[^}]*\})", text, re.M):
            prev = prev | _agg(m.group(1))
            out.append(dict(prev))
        return out

    meant = follow(res.originals[str(src)])
    sent = follow(res.texts[str(src)])
    rows = [r for r in res.reports if r.kind == "pose"]
    assert [r.status for r in rows] == ["partial", "partial", "filtered", "partial", "partial"]
    for r, m, s in zip(rows, meant, sent, strict=True):
        F_meant = B @ _pose(m) @ np.linalg.inv(T)
        q, _, _ = _reaches(nom, cal, B @ _pose(s) @ np.linalg.inv(T), F_meant, near=q10)
        dp, dr = _distance(cal.fk(q) @ T, F_meant @ T)        # at the TCP
        if r.status == "filtered":
            assert dp < TOL_P and dr < TOL_R
        else:
            reported = re.search(r"misses the target by ([\d.]+) mm / ([\d.]+) deg", r.reason)
            assert reported, r.reason
            assert abs(dp * 1e3 - float(reported.group(1))) < 2e-4, r.name
            assert abs(math.degrees(dr) - float(reported.group(2))) < 2e-4, r.name


def test_a_partial_axis_target_is_kept_when_taught_and_listed_when_offline(tmp_path, robots):
    """PTP {A1 15.0}: taught, a joint target that stays; as an offline-programmed one its
    other axes would come from the previous (rewritten) axis target: not filtered."""
    nom, cal, _ = robots["kr6"]
    src = _copy(tmp_path, "hand_moves.src")
    fr = read_frames(str(tmp_path / "krl_frames.yaml"))
    taught = {r.line: r for r in filter_program(str(src), cal, nom, "krl", fr).reports}
    offline = {r.line: r for r in filter_program(str(src), cal, nom, "krl", fr,
                                                  offline_joints=True).reports}
    assert taught[10].status == "kept" and offline[9].status == "filtered"
    assert offline[10].status == "not filtered" and "offline" in offline[10].reason


BAD = [   # (program, old, new, the row's reason, exit code)
    ("spline_cell.dat", "DECL FDAT FP2={TOOL_NO 2,BASE_NO 3,IPO_FRAME #BASE",
     "DECL FDAT FP2={TOOL_NO 2,BASE_NO 3,IPO_FRAME #TCP", "external TCP", 1),
    ("spline_cell.src", "STOOL2(FP2)", "STOOL2(FP99)", "FP99", 1),
    ("weld_seam.src", "FDAT_ACT=FP1", "FDAT_ACT=FGLOBAL", "FDAT_ACT = FGLOBAL", 1),
    ("spline_cell.src", "SLIN XP2 WITH", "SLIN XGLOBAL WITH", "declared outside", 1),
    ("hand_moves.src", "BAS(#INITMOV,0)\r\n", "BAS(#INITMOV,0)\r\nLIN {X 1, Y 2}\r\n",
     "the previous position is not known", 1),
    ("hand_moves.src", "PTP {A1 15.0}", "MOVE_IT()\r\nPTP {A1 15.0}",
     "the previous position (line", 1),
    ("hand_moves.src", "LIN {X 320.0, Y -150.0, Z 480.0}", "LIN {X 320.0, Y P.Y, Z P.Z}",
     "partly computed at run time (Y P.Y), partly written (X)", 1),
    ("hand_moves.src", "LIN {X 320.0, Y -150.0, Z 480.0}", "LIN {X P.X, Y P.Y, Z P.Z}",
     "computed at run time: X P.X", 0),
    ("reassign.script", "wp = p[-0.40, -0.30, 0.20,", "wp = p[-0.40, -0.30, z,",
     "partly computed at run time, partly written", 1),
    ("reassign.script", "  movel(wp, a=1.2, v=0.25)\n  wp = p[-0.40",
     "  movel(wq, a=1.2, v=0.25)\n  wq = p[-0.40", "", 0),
    ("reassign.script", "  wp = p[-0.45",
     "  movel(wz)\n  wz = p[0,0,0,0,0,0]\n  wz = p[1,1,1,0,0,0]\n  wp = p[-0.45",
     "assigned only after its use", 1),
]


@pytest.mark.parametrize("bad", BAD, ids=[f"{b[0]}:{b[3] or 'ok'}" for b in BAD])
def test_each_target_not_filtered_is_listed_with_its_reason(bad, tmp_path, robots, capsys):
    program, old, new, reason, code = bad
    dialect = "urscript" if program.endswith(".script") else "krl"
    robot = "ur5" if dialect == "urscript" else "kr6"
    main = _copy(tmp_path, Path(program).stem + (".script" if dialect == "urscript" else
                                                 ".src"))
    f = tmp_path / program
    raw = f.read_bytes()
    assert old.encode() in raw
    f.write_bytes(raw.replace(old.encode(), new.encode(), 1))
    frames = "spline_frames.yaml" if "spline" in program else "krl_frames.yaml"
    args = ["filter", main, "--robot", robot, "--nominal", robot, "-o", tmp_path / "o" /
            main.name, "--json", tmp_path / "r.json"]
    if dialect == "krl":
        args += ["--frames", tmp_path / frames]
    got, out, err = run(capsys, *args)
    assert got == code, err
    if reason:
        import json

        rows = json.loads((tmp_path / "r.json").read_text())["targets"]
        listed = [r for r in rows if reason in r["reason"]]
        assert listed, rows
        assert all(r["status"] in ("not filtered", "kept") for r in listed)
        if code == 1:
            assert reason in err or "could not be filtered" in err


# --------------------------------------------------------------------------- URScript
def _literals(text: str) -> dict[int, list[float]]:
    """``p[...]`` literals of numbers by line number."""
    out = {}
    for i, line in enumerate(text.splitlines(), 1):
        m = re.search(r"p\[([-\d.,\s]+)\]", line)
        if m:
            out[i] = [float(v) for v in m.group(1).split(",")]
    return out


def _ur_reach(nom, cal, sent: np.ndarray, meant: np.ndarray, tcp: np.ndarray,
              seed: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The nominal controller's joints for TCP pose ``sent`` nearest ``seed`` and the
    calibrated robot's TCP distance there from ``meant``."""
    sol = solve_ik(nom, (sent @ np.linalg.inv(tcp))[None], q0=seed[None], tol_position=1e-12,
                   tol_orientation=1e-12)
    assert sol.success[0]
    q = sol.q[0]
    dp, dr = _distance(cal.fk(q) @ tcp, meant)
    return q, dp, dr


def test_a_pose_variable_assigned_twice_gives_two_targets_each_filtered(tmp_path, robots):
    """reassign.script: `wp` is assigned on lines 5 and 7; the movel on line 6 goes to
    the first value, the one on line 8 to the second (program order); both are filtered
    and listed, the pose_trans of line 9 is listed as computed at run time."""
    nom, cal, _ = robots["ur5"]
    src = _copy(tmp_path, "reassign.script")
    res = filter_program(str(src), cal, nom, "urscript")
    rows = {r.line: r for r in res.reports}
    assert rows[5].status == rows[7].status == "filtered"
    assert rows[10].status == "kept" and "computed at run time" in rows[10].reason
    old, new = _literals(res.originals[str(src)]), _literals(res.texts[str(src)])
    tcp = ur_pose([0, 0, 0.12, 0, 0, 0])
    seed = np.array([0.2, -1.3, 1.6, -1.9, -1.57, 0.4])
    for line in (5, 7):
        assert new[line] != old[line]
        seed, dp, dr = _ur_reach(nom, cal, ur_pose(new[line]), ur_pose(old[line]), tcp, seed)
        assert dp < TOL_P and dr < TOL_R, line


def test_a_polyscope_export_is_filtered_with_each_waypoints_qnear(tmp_path, robots):
    """movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q)), movel, optimovej and
    optimovel (UR 5.21 / 10.8): each waypoint pose is filtered on the branch of its
    qnear; a waypoint relative to a feature, pose_trans(Plane_1, p[...]), in that
    feature's frame (which stays)."""
    nom, cal, _ = robots["ur5"]
    src = _copy(tmp_path, "polyscope_export.script")
    res = filter_program(str(src), cal, nom, "urscript")
    text_old, text_new = res.originals[str(src)], res.texts[str(src)]
    old, new = _literals(text_old), _literals(text_new)
    qs = {int(m.group(1)): np.array([float(v) for v in m.group(2).split(",")])
          for m in re.finditer(r"Waypoint_(\d)_q=\[([^\]]*)\]", text_old)}
    tcp = ur_pose([0, 0, 0.1, 0, 0, 0])
    lines = {1: 7, 2: 9, 3: 11}
    for k, line in lines.items():
        assert new[line] != old[line]
        q, dp, dr = _ur_reach(nom, cal, ur_pose(new[line]), ur_pose(old[line]), tcp, qs[k])
        assert dp < TOL_P and dr < TOL_R, k
        assert np.abs(q - qs[k]).max() < 0.05                      # the qnear branch
    assert [r.status for r in res.reports] == ["filtered"] * 4
    # the waypoint relative to the feature Plane_1: the pose in it is rewritten
    plane = ur_pose(_literals(text_old)[13])
    assert _literals(text_new)[13] == _literals(text_old)[13]
    q, dp, dr = _ur_reach(nom, cal, plane @ ur_pose(new[30]), plane @ ur_pose(old[30]), tcp,
                          qs[1])
    assert dp < TOL_P and dr < TOL_R


@pytest.mark.parametrize("program", ["Go_Home.src", "rsi_driver.src", "eki_driver.src",
                                     "external_control.script"])
def test_a_program_without_local_targets_has_nothing_to_filter(program, tmp_path, capsys):
    robot = "ur5" if program.endswith(".script") else "kr6"
    src = _copy(tmp_path, program)
    code, out, err = run(capsys, "filter", src, "--robot", robot, "--nominal", robot, "-o",
                         tmp_path / "o" / program)
    assert code == 0, err
    assert "nothing to filter" in out
    assert (tmp_path / "o" / program).read_bytes() == src.read_bytes()


def test_a_file_that_is_no_program_is_still_refused(tmp_path, capsys):
    f = tmp_path / "notes.src"
    f.write_text("just some notes\nabout a robot\n")
    code, _, err = run(capsys, "filter", f, "--robot", "kr6", "--nominal", "kr6", "-o",
                       tmp_path / "o.src")
    assert code == 2 and "no motion target found" in err


# --------------------------------------------------------------------------- properties
KR6 = load_serial_robot("kr6")
UR5 = load_serial_robot("ur5")
KR6_CAL = perturb_robot(KR6, np.random.default_rng(11))
UR5_CAL = perturb_robot(UR5, np.random.default_rng(11))
#: x, y, z [mm], A, B, C [deg] of the frames the generated programs use.
_KFRAMES = {"tool": {"1": (10.0, 0.0, 150.0, 0.0, 0.0, 0.0), "2": (-5.0, 20, 180, 0, 30, 0)},
            "base": {"2": (200.0, -100.0, 50.0, 15.0, 0.0, 0.0), "3": (500, 300, -20, -30, 0, 0)}}


def _fmt(v: float, d: int) -> str:
    return f"{v:.{d}f}"


@st.composite
def krl_programs(draw):
    """A .src / .dat from the KRL constructs: FDAT frames named in WITH clauses or
    FDAT_ACT, spline blocks, inline and .dat points, partial aggregates, items the
    filter does not need; targets reachable by construction."""
    cmap = controller_map(KR6)
    base_axes = np.array([10.0, -80, 100, 20, 45, -30])
    src = ["DEF prog( )", "BAS(#INITMOV,0)", "$TOOL = TOOL_DATA[1]", "$BASE = BASE_DATA[2]",
           "PTP {A1 10.0, A2 -80.0, A3 100.0, A4 20.0, A5 45.0, A6 -30.0}"]
    dat = ["DEFDAT prog", 'DECL FDAT F1={TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE,POINT2[] " ",'
           'TQ_STATE FALSE}', "DECL FDAT F2={TOOL_NO 2,BASE_NO 3,IPO_FRAME #BASE}",
           "DECL LDAT L1={VEL 2.0,ORI_TYP #VAR,CB {AUX_PT {ORI #CONSIDER}}}"]
    frames = {"1": ("1", "2"), "2": ("2", "3")}
    active = block = ("1", "2")
    in_block = False
    for k in range(draw(st.integers(1, 6))):
        f = draw(st.sampled_from(["1", "2"]))
        form = draw(st.sampled_from(["with", "block", "fdat_act", "inline", "partial"]))
        if form == "block":
            if not in_block:
                src.append(f"SPLINE WITH $TOOL = STOOL2(F{f}), $BASE = SBASE(F{f}.BASE_NO)")
                in_block, block = True, frames[f]
            tool, base = block
        else:
            if in_block:
                src.append("ENDSPLINE")
                in_block = False
            if form == "fdat_act":
                src.append(f"FDAT_ACT=F{f}")
                active = frames[f]
            tool, base = frames[f] if form == "with" else active
        ax = base_axes + np.array(draw(st.lists(st.floats(-12, 12), min_size=6,
                                                max_size=6)))
        F = KR6.fk(cmap.to_model(ax))
        P = np.linalg.inv(kuka(*_KFRAMES["base"][base])) @ F @ kuka(*_KFRAMES["tool"][tool])
        v = dict(zip("XYZ", P[:3, 3] * 1e3, strict=True)) | dict(
            zip("ABC", _kuka_euler(P[:3, :3]), strict=True))
        d = draw(st.integers(1, 4))
        keys = draw(st.sampled_from(["XYZ", "Z", "ABC", "XY"])) if form == "partial" \
            else "XYZABC"
        agg = "{" + ", ".join(f"{c} {_fmt(v[c], d)}" for c in keys) + "}"
        target = agg
        if form in ("with", "block") and draw(st.booleans()):
            target = f"XP{k}"
            typ = draw(st.sampled_from(["E6POS", "FRAME", "POS"]))
            extra = ",E1 0.0,E2 #NONE" if typ == "E6POS" else ""
            dat.append(f"DECL {typ} {target}={agg[:-1]}{extra}}}")
        if form == "with":
            src.append(f"SLIN {target} WITH $VEL = SVEL_CP(0.5, , L1), $TOOL = STOOL2(F{f}), "
                       f"$BASE = SBASE(F{f}.BASE_NO), $IPO_MODE = SIPO_MODE(F{f}.IPO_FRAME)")
        elif form == "block":
            src.append(f"  {draw(st.sampled_from(['SPL', 'SLIN']))} {target}")
        else:
            src.append(f"LIN {target}")
    if in_block:
        src.append("ENDSPLINE")
    return "\r\n".join(src + ["END", ""]), "\r\n".join(dat + ["ENDDAT", ""])


def _write_frames(path: Path) -> None:
    doc = {"units": {"length": "mm", "angle": "deg"},
           "tool": {int(k): dict(zip(("x", "y", "z", "rz", "ry", "rx"), v, strict=True))
                    for k, v in _KFRAMES["tool"].items()},
           "base": {int(k): dict(zip(("x", "y", "z", "rz", "ry", "rx"), v, strict=True))
                    for k, v in _KFRAMES["base"].items()}}
    path.write_text(yaml.safe_dump(doc))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(program=krl_programs())
def test_property_krl_identity_is_byte_identical_and_calibration_changes_only_numbers(
        program, tmp_path_factory):
    folder = tmp_path_factory.mktemp("krl")
    src_text, dat_text = program
    (folder / "prog.src").write_bytes(src_text.encode("latin-1"))
    (folder / "prog.dat").write_bytes(dat_text.encode("latin-1"))
    _write_frames(folder / "frames.yaml")
    fr = read_frames(str(folder / "frames.yaml"))
    same = filter_program(str(folder / "prog.src"), KR6, KR6, "krl", fr)
    assert same.texts == same.originals
    assert not same.failed, [(r.name, r.reason) for r in same.failed]
    res = filter_program(str(folder / "prog.src"), KR6_CAL, KR6, "krl", fr)
    poses = [r.status for r in res.reports if r.kind == "pose"]
    assert poses and set(poses) <= {"filtered", "partial"}, poses
    assert_only_target_numbers_changed(str(folder / "prog.src"), "krl", res)


@st.composite
def ur_programs(draw):
    """A URScript program: set_tcp, variables (some assigned twice), get_inverse_kin with
    qnear, movel / movep / optimovel with literals or variables, computed values."""
    lines = ["def prog():", "  set_tcp(p[0.0, 0.0, 0.1, 0.0, 0.0, 0.0])"]
    q0 = np.array([0.2, -1.3, 1.6, -1.9, -1.57, 0.4])
    lines.append("  movej([0.2, -1.3, 1.6, -1.9, -1.57, 0.4])")
    tcp = ur_pose([0, 0, 0.1, 0, 0, 0])
    for k in range(draw(st.integers(1, 5))):
        q = q0 + np.array(draw(st.lists(st.floats(-0.2, 0.2), min_size=6, max_size=6)))
        T = UR5.fk(q) @ tcp
        r = log_so3(T[:3, :3])
        d = draw(st.integers(3, 6))
        lit = "p[" + ", ".join(_fmt(float(x), d) for x in [*T[:3, 3], *r]) + "]"
        qlit = "[" + ", ".join(_fmt(float(x), 4) for x in q) + "]"
        form = draw(st.sampled_from(["literal", "var", "ik", "optimovel", "computed",
                                     "feature"]))
        if form == "literal":
            lines.append(f"  movel({lit}, a=1.2, v=0.25)")
        elif form == "var":
            lines += ["  wp = " + lit, "  movep(wp, a=1.2, v=0.25, r=0.01)"]
        elif form == "ik":
            lines += [f"  global W{k}_p={lit}", f"  global W{k}_q={qlit}",
                      f"  movej(get_inverse_kin(W{k}_p, qnear=W{k}_q), a=1.4, v=1.05)"]
        elif form == "optimovel":
            lines += [f"  wp = {lit}", "  optimovel(wp, a=0.3, v=0.3)"]
        elif form == "feature":                  # PolyScope: a waypoint in a feature's frame
            plane = ur_pose([-0.25, -0.4, 0.1, 0.0, 0.0, 1.5708])
            rel = np.linalg.inv(plane) @ T
            lit = "p[" + ", ".join(_fmt(float(x), d) for x in [*rel[:3, 3],
                                                                *log_so3(rel[:3, :3])]) + "]"
            lines += ["  global Plane_1=p[-0.25, -0.4, 0.1, 0.0, 0.0, 1.5708]",
                      f"  movel(pose_trans(Plane_1, {lit}), a=1.2, v=0.25)"]
        else:
            lines.append("  movel(pose_trans(get_actual_tcp_pose(), p[0, 0, 0.01, 0, 0, 0]))")
    return "\n".join(lines + ["end", "prog()", ""])


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(program=ur_programs())
def test_property_urscript_identity_is_byte_identical_and_calibration_changes_only_numbers(
        program, tmp_path_factory):
    folder = tmp_path_factory.mktemp("ur")
    (folder / "prog.script").write_text(program)
    same = filter_program(str(folder / "prog.script"), UR5, UR5, "urscript")
    assert same.texts == same.originals
    assert not same.failed, [(r.name, r.reason) for r in same.failed]
    res = filter_program(str(folder / "prog.script"), UR5_CAL, UR5, "urscript")
    assert {r.status for r in res.reports if r.kind == "pose"} <= {"filtered"}
    assert all(r.status == "kept" for r in res.reports if r.kind != "pose")
    assert_only_target_numbers_changed(str(folder / "prog.script"), "urscript", res)
