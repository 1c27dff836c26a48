"""No traceback on any input: a property / fuzz suite over every reader and command.

``KINCAL_FUZZ_EXAMPLES=400 KINCAL_FUZZ_RANDOM=1 pytest tests/test_fuzz.py`` digs deeper
(more examples, a new random draw each run) than the default profile.

Hypothesis generates bad measurement files (empty, header only, binary, Latin-1, BOM,
NaN / Inf, 1e308, ragged rows, duplicate columns, cut anywhere, cells replaced), bad
robot files (YAML and URDF: keys missing or mistyped, cycles, an unreachable tip,
unknown joint types, entity-expansion bombs and external entities), bad setup files,
result files, socket folders, five-bar files and bad option values, and runs the
command lines on them.  The contract, for every one:

* exit status 0 (the input happened to be fine), 1 (a result that failed its checks) or
  2 (bad input) - never a traceback, never "internal error";
* on 1 or 2, stderr is one line starting with ``error:``;
* on 2, no output file exists afterwards;
* the inputs are never changed.

Fixed cases (a folder, a missing file, -o equal to --data, an unwritable output) are
checked alongside.  The default profile keeps the run to a few tens of seconds.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from pathlib import Path

import pytest
from cli_helpers import invoke
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FUZZ = settings(max_examples=int(os.environ.get("KINCAL_FUZZ_EXAMPLES", "50")),
                deadline=None, derandomize=not os.environ.get("KINCAL_FUZZ_RANDOM"),
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])


# --------------------------------------------------------------------------- harness
def run(*args: object) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = invoke(*args)
    return code, out.getvalue(), err.getvalue()


def contract(args: list[object], outputs: list[Path], inputs: list[Path]) -> int:
    """Run ``kincal ARGS`` and check the contract; returns the exit status."""
    before = {p: _snapshot(p) for p in inputs}
    for p in outputs:
        if p.is_file():
            p.unlink()
    code, out, err = run(*args)
    cmd = " ".join(map(str, args))
    assert code in (0, 1, 2), f"kincal {cmd}: exit {code}: {err}"
    assert "Traceback" not in out + err and "internal error" not in err, f"kincal {cmd}: {err}"
    if code != 0:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), f"kincal {cmd}: {err!r}"
    if code == 2:
        left = [p for p in outputs if p.exists()]
        assert not left, f"kincal {cmd}: exit 2 but wrote {left}"
    if code == 1 and args[0] == "calibrate" and "--force" not in args and "-o" in args:
        robot_file = Path(str(args[args.index("-o") + 1]))
        assert not robot_file.exists(), f"kincal {cmd}: exit 1 but wrote {robot_file}"
    for p, snap in before.items():
        assert _snapshot(p) == snap, f"kincal {cmd}: changed the input {p}"
    return code


def _snapshot(p: Path) -> object:
    if p.is_dir():
        return sorted((q.name, q.read_bytes()) for q in p.iterdir() if q.is_file())
    return p.read_bytes() if p.exists() else None


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, Path]:
    """Small valid files every case starts from."""
    d = tmp_path_factory.mktemp("fuzz")
    files = {"csv": d / "good.csv", "yaml": d / "good.yaml", "urdf": d / "good.urdf",
             "res": d / "good.json", "cal": d / "cal.yaml", "fb": d / "fivebar.csv"}
    assert invoke("simulate", "puma560", "-o", files["csv"], "-n", "12", "--length-unit",
                  "mm", "--angle-unit", "deg", "--seed", "1") == 0
    assert invoke("export", "puma560", "-o", files["yaml"]) == 0
    assert invoke("export", "puma560", "-o", files["urdf"]) == 0
    assert invoke("calibrate", "puma560", "--data", files["csv"], "-o", files["cal"],
                  "--json", files["res"], "--force") in (0, 1)
    assert invoke("fivebar-simulate", "fivebar_reference", "-o", files["fb"], "-n", "8") == 0
    return files


# --------------------------------------------------------------------------- measurement files
PATHOLOGICAL = {
    "empty": b"", "whitespace": b"  \n\t\n", "binary": bytes(range(256)) * 3,
    "nul": b"q1_deg,x_mm\n1\x00,2\n", "only comments": b"# kincal measurements: "
    b"instrument=position\n# nothing\n",
}
CELLS = ["", " ", "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e-320", "abc", "1,5",
         "\x00", "é", '"', "0x10", "1e", "--1", "١٢", "9" * 400]


@st.composite
def measurement_text(draw: st.DrawFn, base: str) -> bytes:
    """A measurement file broken in one to three ways."""
    kind = draw(st.sampled_from(["mutate", "pathological", "bytes", "truncate"]))
    if kind == "pathological":
        return PATHOLOGICAL[draw(st.sampled_from(sorted(PATHOLOGICAL)))]
    if kind == "bytes":
        return draw(st.binary(max_size=300))
    if kind == "truncate":
        raw = base.encode()
        return raw[:draw(st.integers(0, len(raw)))]
    lines = base.splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cell", "drop line", "dup column", "ragged", "header cell",
                                   "bom", "latin1", "crlf", "extra column", "drop tag",
                                   "other angle unit", "beyond a limit", "swap joints",
                                   "one row", "repeat a row"]))
        if op == "cell" and len(lines) > head + 1:
            i = draw(st.integers(head + 1, len(lines) - 1))
            cells = lines[i].split(",")
            cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(CELLS))
            lines[i] = ",".join(cells)
        elif op == "drop line" and lines:
            del lines[draw(st.integers(0, len(lines) - 1))]
        elif op == "dup column" and len(lines) > head:
            cols = lines[head].split(",")
            if len(cols) > 1:
                cols[1] = cols[0]
                lines[head] = ",".join(cols)
        elif op == "ragged" and len(lines) > head + 1:
            i = draw(st.integers(head + 1, len(lines) - 1))
            lines[i] += ",1" if draw(st.booleans()) else ""
            lines[i] = lines[i].rsplit(",", 2)[0] if not lines[i].endswith(",1") else lines[i]
        elif op == "header cell" and len(lines) > head:
            cols = lines[head].split(",")
            cols[draw(st.integers(0, len(cols) - 1))] = draw(st.sampled_from(
                ["", "x", "q7_deg", "x_feet", "q1", "x_mm", "sigma_rad", "é_mm", "q1_deg"]))
            lines[head] = ",".join(cols)
        elif op == "extra column" and len(lines) > head:
            lines = lines[:head] + [lines[head] + ",x9_mm"] + [ln + ",1" for ln in
                                                                lines[head + 1:]]
        elif op == "drop tag" and lines and lines[0].startswith("#"):
            lines = lines[1:]
            head = max(0, head - 1)
        else:
            lines = _model_cannot_explain(draw, op, lines, head)
    text = "\n".join(lines) + "\n"
    enc = draw(st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "crlf"]))
    if enc == "crlf":
        return text.replace("\n", "\r\n").encode()
    return text.encode(enc, errors="replace")


def _model_cannot_explain(draw: st.DrawFn, op: str, lines: list[str], head: int
                          ) -> list[str]:
    """Files the readers accept but the model cannot explain (the gate's cases):
    joint headers in the other angle unit, a reading beyond a joint limit, two joint
    columns swapped, one row, one row repeated."""
    if len(lines) <= head + 1:
        return lines
    rows = lines[head + 1:]
    if op == "other angle unit":
        swap = {"_deg": "_rad", "_rad": "_deg"}
        lines[head] = ",".join(c[:-4] + swap.get(c[-4:], c[-4:]) for c in
                               lines[head].split(","))
    elif op == "beyond a limit":
        i = draw(st.integers(head + 1, len(lines) - 1))
        cells = lines[i].split(",")
        cells[min(1, len(cells) - 1)] = draw(st.sampled_from(["300", "-300", "1e4", "5.2"]))
        lines[i] = ",".join(cells)
    elif op == "swap joints":
        def swapped(ln: str) -> str:
            c = ln.split(",")
            return ",".join([c[1], c[0], *c[2:]]) if len(c) > 1 else ln
        lines = lines[:head + 1] + [swapped(ln) for ln in rows]
    elif op == "one row":
        lines = lines[:head + 1] + rows[:draw(st.integers(1, 2))]
    elif op == "repeat a row":
        lines = lines[:head + 1] + [rows[0]] * draw(st.integers(2, 212))
    return lines


@FUZZ
@given(data=st.data())
def test_measurement_files(good, tmp_path_factory, data):
    d = tmp_path_factory.mktemp("m")
    f = d / "m.csv"
    f.write_bytes(data.draw(measurement_text(good["csv"].read_text())))
    out = d / "out.yaml"
    cmd = data.draw(st.sampled_from([
        ["calibrate", "puma560", "--data", f, "-o", out, "--max-iter", "20"],
        ["identifiability", "puma560", "--data", f],
        ["validate", "puma560", "--data", f, "--json", out],
        ["compensate", "puma560", "--targets", f, "-o", out],
        ["plan", "puma560", "-o", out, "--candidates-file", f, "-n", "4", "--grid", "1"],
        ["init", "puma560", "--data", f, "-o", out],
        ["calibrate", good["urdf"], "--data", f, "-o", out, "--max-iter", "20"]]))
    contract(cmd, [out], [f])


# --------------------------------------------------------------------------- robot files
YAML_VALUES = [None, "", "x", "ninety", -1, 0, 1e308, float("nan"), [], {}, [1, 2, 3],
               {"a": 1}, True, "1e999", "helical"]


@st.composite
def robot_yaml(draw: st.DrawFn, base: str) -> bytes:
    import yaml

    doc = yaml.safe_load(base)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["drop key", "set key", "joint field", "bytes", "text"]))
        if op == "bytes":
            return draw(st.binary(max_size=200))
        if op == "text":
            return draw(st.text(max_size=200)).encode()
        if op == "drop key" and doc:
            doc.pop(draw(st.sampled_from(sorted(doc))), None)
        elif op == "set key":
            doc[draw(st.sampled_from(["units", "convention", "joints", "base", "tool", "kind",
                                      "name", "joint_units", "tolerances"]))] = \
                draw(st.sampled_from(YAML_VALUES))
        elif op == "joint field" and isinstance(doc.get("joints"), list) and doc["joints"]:
            j = doc["joints"][draw(st.integers(0, len(doc["joints"]) - 1))]
            if isinstance(j, dict):
                j[draw(st.sampled_from(["a", "d", "alpha", "type", "limits", "name",
                                        "theta_offset"]))] = draw(st.sampled_from(YAML_VALUES))
    return yaml.safe_dump(doc, allow_unicode=True).encode()


@FUZZ
@given(data=st.data())
def test_robot_yaml_files(good, tmp_path_factory, data):
    d = tmp_path_factory.mktemp("r")
    f = d / "robot.yaml"
    f.write_bytes(data.draw(robot_yaml(good["yaml"].read_text())))
    out = d / "out.urdf"
    cmd = data.draw(st.sampled_from([["show", f], ["fk", f, "--q", "0,0,0,0,0,0"],
                                     ["export", f, "-o", out],
                                     ["calibrate", f, "--data", good["csv"], "-o", out]]))
    contract(cmd, [out], [f])


ENTITY_BOMB = ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
               + "".join(f'<!ENTITY a{i} "{("&a" + (str(i - 1) if i > 1 else "") + ";") * 10}">'
                         for i in range(1, 9))
               + ']><robot name="&a8;"><link name="l"/></robot>')
EXTERNAL = ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/hostname">]>'
            '<robot name="&x;"><link name="l"/></robot>')


@st.composite
def urdf_text(draw: st.DrawFn, base: str) -> bytes:
    kind = draw(st.sampled_from(["mutate", "bomb", "external", "bytes", "cycle", "type"]))
    if kind == "bomb":
        return ENTITY_BOMB.encode()
    if kind == "external":
        return EXTERNAL.encode()
    if kind == "bytes":
        return draw(st.binary(max_size=300))
    if kind == "cycle":
        return base.replace('<parent link="base_link"', '<parent link="tool_link"', 1).encode()
    if kind == "type":
        new = draw(st.sampled_from(["screw", "", "x"]))
        return base.replace('type="revolute"', f'type="{new}"', 1).encode()
    text = base
    for _ in range(draw(st.integers(1, 3))):
        target = draw(st.sampled_from(['xyz="', 'rpy="', 'lower="', 'upper="', 'link="',
                                       'name="', "<axis", "</joint>", "<robot", "/>"]))
        at = text.find(target, draw(st.integers(0, max(0, len(text) - 1))))
        if at < 0:
            at = text.find(target)
        if at < 0:
            continue
        insert = draw(st.sampled_from(["nan ", "1e308 ", "x ", "", "<", "&", '"', "0 0 0 ",
                                       "&ent;"]))
        if draw(st.booleans()):
            text = text[:at + len(target)] + insert + text[at + len(target):]
        else:
            text = text[:at] + text[at + len(target):]
    return text.encode()


@FUZZ
@given(data=st.data())
def test_urdf_files(good, tmp_path_factory, data):
    d = tmp_path_factory.mktemp("u")
    f = d / "robot.urdf"
    raw = data.draw(urdf_text(good["urdf"].read_text()))
    f.write_bytes(raw)
    out = d / "out.yaml"
    links = data.draw(st.sampled_from([[], ["--tip-link", "tool_link"],
                                       ["--tip-link", "no_such_link"],
                                       ["--base-link", "tool_link", "--tip-link",
                                        "base_link"]]))
    cmd = data.draw(st.sampled_from([["show", f, *links],
                                     ["export", f, *links, "-o", out],
                                     ["fk", f, *links, "--q", "0,0,0,0,0,0"]]))
    code = contract(cmd, [out], [f])
    if raw in (ENTITY_BOMB.encode(), EXTERNAL.encode()):
        assert code == 2                                   # refused, not expanded


# --------------------------------------------------------------------------- other readers
SETUP_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats(allow_nan=True)
    | st.sampled_from(["puma560", "good.csv", "x?", "mm", "0deg", "1mm", "training",
                       "mukca", "nope.csv", "", "*"]),
    lambda c: st.lists(c, max_size=3) | st.dictionaries(
        st.sampled_from(["file", "units", "ignore", "name", "format", "options", "frames",
                         "free", "prior", "max_iter", "q1", "output", "x?"]), c, max_size=3),
    max_leaves=8)


@FUZZ
@given(doc=st.dictionaries(st.sampled_from(["robot", "base_link", "tip_link", "hold", "data",
                                            "validate", "calibration", "outputs", "extra"]),
                           SETUP_VALUES, max_size=5))
def test_setup_files(good, tmp_path_factory, doc):
    import yaml

    d = tmp_path_factory.mktemp("s")
    (d / "good.csv").write_bytes(good["csv"].read_bytes())
    f = d / "setup.yaml"
    f.write_text(yaml.safe_dump(doc))
    contract(["calibrate", "--config", f, "-o", d / "out.yaml", "--max-iter", "10"],
             [d / "out.yaml"], [f, d / "good.csv"])


@FUZZ
@given(raw=st.one_of(st.binary(max_size=200), st.text(max_size=200).map(str.encode),
                     st.sampled_from([b"{}", b"[]", b'{"parameters": 1}',
                                      b'{"parameters": [{"name": "a[2]"}]}',
                                      b'{"parameters": [{"name": "a[2]", "estimate": "x"}]}'])),
       which=st.sampled_from(["result", "fivebar", "socket", "program", "ur", "manifest"]))
def test_other_readers(good, tmp_path_factory, raw, which):
    d = tmp_path_factory.mktemp("o")
    f = d / ("sock" if which == "socket" else "in.src" if which == "program" else "in.txt")
    out = d / "out.yaml"
    if which == "socket":
        f.mkdir()
        (f / "hole_0.csv").write_bytes(raw)
        (f / "hole_1.csv").write_bytes(raw)
        cmd = ["calibrate", "puma560", "--data", f, "--instrument", "two-socket", "--option",
               "length=50mm", "-o", out]
    elif which == "result":
        f.write_bytes(raw)
        cmd = ["validate", "puma560", "--data", good["csv"], "--result", f, "--json", out]
    elif which == "fivebar":
        f.write_bytes(raw)
        cmd = ["calibrate", "fivebar_reference", "--data", f, "-o", out]
    elif which == "ur":
        f.write_bytes(raw)
        cmd = ["import", "ur", f, "--nominal", "ur5", "-o", out]
    elif which == "manifest":
        f.write_bytes(raw)
        out = d / "fleet.db"
        cmd = ["fleet", "calibrate", f, "--db", out]
    else:
        f.write_bytes(raw)
        cmd = ["filter", f, "--robot", "puma560", "--nominal", "puma560", "-o", d / "out.src"]
        out = d / "out.src"
    contract(cmd, [out], [f])


# --------------------------------------------------------------------------- options
OPTION_TEXT = st.one_of(st.text(max_size=20), st.sampled_from(
    ["0", "-1mm", "nan", "infmm", "1e308mm", "1e999", "1,2,3", "1mmm", "1 mm", "1deg", "1s",
     "1px", "0.01", "--", "°", "1e-400mm", ",,", "1;2", "5arcsec"]))


@FUZZ
@given(value=OPTION_TEXT, which=st.integers(0, 11))
def test_option_values(tmp_path_factory, value, which):
    d = tmp_path_factory.mktemp("opt")
    out = d / "out.csv"
    cmd = [
        ["simulate", "puma560", "-o", out, "-n", "5", "--noise", value],
        ["simulate", "puma560", "-o", out, "-n", "5", "--length-error", value],
        ["fk", "puma560", "--q", value],
        ["jacobian", "puma560", "--q", value, "--deg"],
        ["ik", "puma560", "--position", value],
        ["ik", "puma560", "--pose", value, "--tol-position", "1e-3mm"],
        ["trajectory", "puma560", "--start", "0,0,0,0,0,0", "--end", "0.1,0,0,0,0,0",
         "--duration", value, "--out-dir", d / "t"],
        ["trajectory", "puma560", "--start", "0,0,0,0,0,0", "--end", "0.1,0,0,0,0,0",
         "--duration", "1s", "--dt", value, "--out-dir", d / "t"],
        ["plan", "puma560", "-o", out, "-n", "4", "--candidates", "40", "--grid", "1",
         "--noise", value],
        ["calibrate", "puma560", "--data", out, "--prior", value],
        ["calibrate", "puma560", "--data", out, "--hold", f"q6={value}"],
        ["fk", "puma560", "--q", "0,0,0,0,0,0", "--si", "--json",
         str(d / ("j" + value.replace("/", "_").replace(os.sep, "_")))],   # stays in tmp
    ][which]
    if which in (9, 10):
        assert invoke("simulate", "puma560", "-o", out, "-n", "12", "--seed", "3") == 0
        contract(cmd, [d / "never.yaml"], [out])
    else:
        contract(cmd, [out] if which not in (2, 3, 4, 5, 11) else [], [])


# --------------------------------------------------------------------------- fixed cases
@pytest.mark.parametrize("args_of", [
    lambda g, d: ["calibrate", "puma560", "--data", g["csv"], "-o", g["csv"]],
    lambda g, d: ["calibrate", "puma560", "--data", g["csv"], "--json", g["csv"]],
    lambda g, d: ["calibrate", "puma560", "--data", g["csv"], "--report", g["csv"]],
    lambda g, d: ["calibrate", g["urdf"], "--data", g["csv"], "--urdf", g["urdf"], "-o",
                  d / "c.yaml"],
    lambda g, d: ["compensate", "puma560", "--targets", g["csv"], "-o", g["csv"]],
    lambda g, d: ["simulate", g["yaml"], "-o", g["yaml"]],
    lambda g, d: ["init", "puma560", "--data", g["csv"], "-o", g["csv"]],
    lambda g, d: ["calibrate", "puma560", "--data", d, "-o", d / "c.yaml"],
    lambda g, d: ["calibrate", "puma560", "--data", d / "missing.csv", "-o", d / "c.yaml"],
    lambda g, d: ["show", d],
    lambda g, d: ["show", d / "missing.yaml"],
    lambda g, d: ["calibrate", "puma560", "--data", g["csv"], "-o", d],
    lambda g, d: ["calibrate", "puma560", "--data", g["csv"], "-o", g["csv"] / "c.yaml"],
    lambda g, d: ["export", "puma560", "-o", g["csv"] / "x.urdf"],
    lambda g, d: ["simulate", "puma560", "-o", d],
    lambda g, d: ["trajectory", "puma560", "--start", "0,0,0,0,0,0", "--end", "0.1,0,0,0,0,0",
                  "--duration", "1s", "--out-dir", g["csv"]],
    lambda g, d: ["validate", "puma560", "--data", g["csv"], "--result", d],
    lambda g, d: ["calibrate", "--config", d],
], ids=["-o is --data", "--json is --data", "--report is --data", "--urdf is ROBOT",
        "compensate -o is --targets", "simulate -o is ROBOT", "init -o is --data",
        "data is a folder", "data missing", "robot is a folder", "robot missing",
        "-o is a folder", "-o under a file", "export under a file", "simulate -o folder",
        "--out-dir is a file", "result is a folder", "config is a folder"])
def test_fixed_cases(good, tmp_path, args_of):
    args = args_of(good, tmp_path)
    code = contract(args, [tmp_path / "c.yaml"], [p for p in good.values()])
    assert code == 2


# --------------------------------------------------------------------------- the gate
def _rewrite(src: Path, dst: Path, change) -> Path:
    lines = src.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    dst.write_text("\n".join(change(lines[:head + 1], lines[head + 1:])) + "\n")
    return dst


def _to_radians(row: str) -> str:
    c = row.split(",")
    return ",".join([repr(math.radians(float(v))) for v in c[:6]] + c[6:])


GATE_FILES = {
    "degrees under _rad": lambda h, r: [*h[:-1], h[-1].replace("_deg", "_rad"), *r],
    "radians under _deg": lambda h, r: [*h, *(_to_radians(x) for x in r)],
    "q2 = 300 deg": lambda h, r: [*h, r[0], ",".join([r[1].split(",")[0], "300",
                                                      *r[1].split(",")[2:]]), *r[2:]],
    "joint columns swapped": lambda h, r: [*h, *(",".join([x.split(",")[1], x.split(",")[0],
                                                           *x.split(",")[2:]]) for x in r)],
    "one row": lambda h, r: [*h, r[0]],
    "two rows": lambda h, r: [*h, *r[:2]],
    "212 identical rows": lambda h, r: [*h, *[r[0]] * 212],
}


@pytest.mark.parametrize("case", sorted(GATE_FILES))
def test_data_the_model_cannot_explain_is_refused(good, tmp_path, case):
    """Exit 1, one line, no calibrated robot (issue: "never silently wrong"); with
    ``--force`` the robot is written and the status is still 1."""
    f = _rewrite(good["csv"], tmp_path / "data.csv", GATE_FILES[case])
    out = tmp_path / "c.yaml"
    code = contract(["calibrate", "puma560", "--data", f, "-o", out], [out], [f])
    assert code == 1 and not out.exists()
    assert contract(["calibrate", "puma560", "--data", f, "-o", out, "--force"], [out],
                    [f]) == 1 and out.exists()


@pytest.mark.parametrize("args, status", [
    (["--free", ","], 2), (["--fix", "*"], 2), (["--loss-scale", "0"], 2),
    (["--loss-scale", "-1"], 2), (["--loss-scale", "nan"], 2)])
def test_nothing_to_estimate_is_bad_input(good, tmp_path, args, status):
    out = tmp_path / "c.yaml"
    assert contract(["calibrate", "puma560", "--data", good["csv"], "-o", out, *args], [out],
                    [good["csv"]]) == status


def test_joints_beyond_the_limits_elsewhere(good, tmp_path):
    f = _rewrite(good["csv"], tmp_path / "data.csv", GATE_FILES["q2 = 300 deg"])
    j = tmp_path / "v.json"
    assert contract(["validate", "puma560", "--data", f, "--json", j], [j], [f]) == 1
    assert not j.exists()
    assert contract(["fk", "puma560", "--q", "10,20,30,40,50,60"], [], []) == 1
    assert contract(["fk", "puma560", "--q", "10,20,30,40,50,60", "--deg"], [], []) == 0


@pytest.mark.parametrize("args_of", [
    lambda d: ["ik", "puma560", "--position", "0.4,0.1,0.3m", "--q0", "0,5,0,0,0,0"],
    lambda d: ["trajectory", "puma560", "--start", "0,0,0,0,0,0", "--end", "0,5,0,0,0,0",
               "--duration", "1s", "--out-dir", d / "t"],
    lambda d: ["trajectory", "puma560", "--start", "0,300deg,0,0,0,0", "--end",
               "0,0,0,0,0,0", "--duration", "1s", "--out-dir", d / "t"],
    lambda d: ["clik", "puma560", "--start", "0,5,0,0,0,0", "--end-position", "400,0,300mm",
               "--method", "dls", "--out-dir", d / "t"],
], ids=["ik --q0", "trajectory --end", "trajectory --start", "clik --start"])
def test_joint_options_beyond_the_limits(tmp_path, args_of):
    """Joint values beyond the limits given as an option: exit 1, one line, nothing
    written (q2 = 5 rad = 286 deg where the PUMA's limit is 225 deg)."""
    assert contract(args_of(tmp_path), [tmp_path / "t"], []) == 1
    assert not (tmp_path / "t").exists()


def test_compensate_seeds_beyond_the_limits(tmp_path):
    f = tmp_path / "targets.csv"
    f.write_text("x_mm,y_mm,z_mm,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
                 "400,100,300,0,300,0,0,0,0\n")
    out = tmp_path / "c.csv"
    assert contract(["compensate", "puma560", "--targets", f, "-o", out], [out], [f]) == 1
    assert not out.exists()
