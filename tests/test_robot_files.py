"""Robot YAML files: round trips, one-line errors for bad files (through the CLI), and
property tests that throw random documents at the reader."""

from __future__ import annotations

import copy
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from kincal.errors import KincalError, RobotFileError
from kincal.robots.chain import ChainBuilder, Robot
from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import (
    library_dir,
    load_serial_robot,
    read_robot_yaml,
    robot_from_dict,
    robot_to_dict,
    write_robot_yaml,
)

PI = np.pi
RNG = np.random.default_rng(5)
PUMA_DOC = yaml.safe_load((library_dir() / "puma560.yaml").read_text())


# --------------------------------------------------------------------------- round trips
def _dh_robot(convention: str = "standard", beta: bool = False) -> Robot:
    tab = [(0, 0.1, PI / 2), (0.4318, 0, 0), (0.0203, 0.15005, -PI / 2), (0, 0.4318, PI / 2)]
    links = [DHLink(a=a, d=d, alpha=al, theta_offset=0.01 * i, name=f"joint_{i}",
                    beta=(0.002 * i if beta else None), lower=-2.0 - i, upper=2.0 + i)
             for i, (a, d, al) in enumerate(tab)]
    links.append(DHLink(a=0.0, d=0.3, alpha=0.0, joint="prismatic", lower=0.0, upper=0.25,
                        beta=(0.0 if beta else None)))
    links.append(DHLink(a=0.02, d=0.05, alpha=-PI / 2))        # unlimited
    return from_dh(links, convention, name="arm", base=(0.1, -0.2, 0.3, 0.03, 0.02, 0.01),
                   tool=(0.0, 0.01, 0.12, 0.3, 0.2, -0.1),
                   meta={"source": "unit test", "description": "a test arm"})


def _ets_robot() -> Robot:
    b = ChainBuilder("ets_arm")
    b.frame("base", [0.0, 0.0, 0.2, 0.0, 0.0, 0.1])
    j1 = b.joint("shoulder", "revolute", -3.0, 3.0)
    j2 = b.joint("slide", "prismatic", 0.0, 0.5)
    j3 = b.joint("wrist", "revolute")
    b.transform("Rz", "shoulder.offset", 0.05, role="offset", joint=j1)
    b.transform("Rx", None, PI / 2)
    b.transform("Ty", "l1", 0.3)
    b.transform("Tz", None, 0.1, joint=j2, scale=-1.0)
    b.transform("Ry", "wrist.offset", -0.1, role="offset", joint=j3, scale=-1.0)
    b.transform("Tx", "l2", 0.07, role="length")
    b.frame("tool", [0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
    return b.build(meta={"convention": "ets", "source": "unit test"})


ROUND_TRIP = {
    "standard_dh": lambda: _dh_robot("standard"),
    "modified_dh": lambda: _dh_robot("modified"),
    "hayati": lambda: _dh_robot("standard", beta=True),
    "ets": _ets_robot,
    "puma560": lambda: load_serial_robot("puma560"),
}


@pytest.mark.parametrize("make", ROUND_TRIP.values(), ids=ROUND_TRIP.keys())
def test_yaml_round_trip(make, tmp_path):
    robot = make()
    path = tmp_path / "robot.yaml"
    write_robot_yaml(robot, path)
    back = read_robot_yaml(path)
    assert back.name == robot.name
    assert back.param_names == robot.param_names
    np.testing.assert_array_equal(back.param_values, robot.param_values)  # exact
    assert back.param_units == robot.param_units
    assert back.param_roles == robot.param_roles
    assert back.joints == robot.joints
    assert back.meta["convention"] == robot.meta["convention"]
    assert back.meta.get("source") == robot.meta.get("source")
    assert [(e.kind, e.joint, e.scale) for e in back.ets] == \
        [(e.kind, e.joint, e.scale) for e in robot.ets]
    Q = RNG.uniform(-1, 1, (10, robot.n))
    np.testing.assert_array_equal(back.fk(Q), robot.fk(Q))
    doc = yaml.safe_load(path.read_text())
    assert doc["units"] == {"length": "m", "angle": "rad"}
    assert robot_to_dict(back) == robot_to_dict(robot)
    assert not list(tmp_path.glob(".robot.yaml.*"))               # no temp file left


def test_units_are_converted_at_the_border(tmp_path):
    si = copy.deepcopy(PUMA_DOC)
    si["units"] = {"length": "m", "angle": "rad"}
    mm = copy.deepcopy(PUMA_DOC)
    mm["units"] = {"length": "mm", "angle": "deg"}
    for row in si["joints"]:
        row["alpha"] = np.deg2rad(row["alpha"]).item()
        row["limits"] = np.deg2rad(row["limits"]).tolist()
    for row in mm["joints"]:
        row["a"] = row["a"] * 1e3
        row["d"] = row["d"] * 1e3
    mm["tool"] = {"z": 100.0, "rx": 90.0}
    si["tool"] = {"z": 0.1, "rx": PI / 2}
    a, b = robot_from_dict(si, "si.yaml"), robot_from_dict(mm, "mm.yaml")
    np.testing.assert_allclose(a.param_values, b.param_values, rtol=1e-15, atol=1e-17)
    np.testing.assert_allclose(a.joint_limits, b.joint_limits, rtol=1e-15)
    lib = load_serial_robot("puma560")
    assert lib.params()["a[2]"] == 0.4318 and lib.params()["alpha[1]"] == PI / 2
    np.testing.assert_allclose(lib.joint_limits[0], np.deg2rad([-160, 160]), rtol=1e-15)


# --------------------------------------------------------------------------- bad files
def _doc(**changes) -> dict:
    d = copy.deepcopy(PUMA_DOC)
    d.pop("source")
    d.update(changes)
    return {k: v for k, v in d.items() if v is not ...}


def _row(i: int = 0, **changes) -> dict:
    d = copy.deepcopy(PUMA_DOC)
    d.pop("source")
    d["joints"][i].update(changes)
    d["joints"][i] = {k: v for k, v in d["joints"][i].items() if v is not ...}
    return d


ETS_OK = {"name": "e", "units": {"length": "m", "angle": "rad"}, "convention": "ets",
          "joints": [{"name": "q1", "type": "revolute"}, {"name": "q2", "type": "prismatic"}],
          "chain": [{"transform": "Rz", "name": "t1", "joint": "q1"},
                    {"transform": "Tz", "name": "d2", "value": 0.1, "joint": "q2"}]}


def _ets(**changes) -> dict:
    d = copy.deepcopy(ETS_OK)
    d.update(changes)
    return d


HUGE = "1" * 400
# name -> (file text or bytes, text the one-line error must contain, xfail reason or None)
BAD_FILES: dict[str, tuple[str | bytes, str, str | None]] = {
    "missing_units": (_doc(units=...), "'units'", None),
    "missing_convention": (_doc(convention=...), "'convention'", None),
    "missing_joints": (_doc(joints=...), "'joints'", None),
    "missing_a": (_row(2, a=...), "'joints[2].a'", None),
    "missing_type": (_row(1, type=...), "'joints[1].type'", None),
    "missing_units_length": (_doc(units={"angle": "deg"}), "'units.length'", None),
    "joints_not_list": (_doc(joints="q1 q2"), "'joints'", None),
    "joints_empty": (_doc(joints=[]), "'joints'", None),
    "row_not_mapping": (_doc(joints=[[0, 0, 0]]), "'joints[0]'", None),
    "a_string": (_row(0, a="ten"), "'joints[0].a'", None),
    "a_bool": (_row(0, a=True), "'joints[0].a'", None),
    "alpha_list": (_row(3, alpha=[1, 2]), "'joints[3].alpha'", None),
    "units_list": (_doc(units=["m", "deg"]), "'units'", None),
    "name_number": (_doc(name=5), "'name'", None),
    "limits_scalar": (_row(0, limits=3), "'joints[0].limits'", None),
    "limits_reversed": (_row(0, limits=[10, -10]), "'joints[0].limits'", None),
    "base_not_mapping": (_doc(base=[0, 0, 0]), "'base'", None),
    "base_unknown_field": (_doc(base={"x": 0, "yaw": 1}), "'base.yaw'", None),
    "unknown_dh_field": (_row(0, length=1), "'joints[0].length'", None),
    "unknown_joint_type": (_row(4, type="spherical"), "'joints[4].type'", None),
    "nan_a": ("__NAN__", "'joints[1].a'", None),
    "nan_base": (_doc(base={"x": float("nan")}), "'base.x'", None),
    "nan_limit": (_row(0, limits=[float("nan"), 1]), "'joints[0].limits[0]'", None),
    "nan_word": (_row(0, d="NaN"), "'joints[0].d'", None),
    "inf_d": (_row(2, d=float("inf")), "'joints[2].d'", None),
    "neg_inf_tool": (_doc(tool={"rz": float("-inf")}), "'tool.rz'", None),
    "overflow_float": ("__OVERFLOW__", "'joints[0].a'", None),
    "bad_length_unit": (_doc(units={"length": "km", "angle": "deg"}), "'units.length'", None),
    "bad_angle_unit": (_doc(units={"length": "m", "angle": "grad"}), "'units.angle'", None),
    "unknown_convention": (_doc(convention="dh"), "'convention'", None),
    "beta_not_hayati": (_row(1, beta=0.1), "'joints[1].beta'", None),
    "unknown_kind": (_doc(kind="delta"), "'kind'", None),
    "duplicate_joint_dh": (_row(1, name="q1"), "'joints'", None),
    "duplicate_joint_ets": (_ets(joints=[{"name": "q1", "type": "revolute"},
                                         {"name": "q1", "type": "prismatic"}]),
                            "'joints[1].name'", None),
    "duplicate_param_ets": (_ets(chain=[{"transform": "Rz", "name": "t1", "joint": "q1"},
                                        {"transform": "Tz", "name": "t1", "joint": "q2"}]),
                            "'chain[1].name'", None),
    "ets_unknown_transform": (_ets(chain=[{"transform": "Rw", "joint": "q1"}]),
                              "'chain[0].transform'", None),
    "ets_unknown_joint": (_ets(chain=[{"transform": "Rz", "joint": "q9"}]),
                          "'chain[0].joint'", None),
    "ets_joint_twice": (_ets(chain=[{"transform": "Rz", "joint": "q1"},
                                    {"transform": "Rx", "joint": "q1"},
                                    {"transform": "Tz", "joint": "q2"}]),
                        "'chain[1].joint'", None),
    "ets_kind_mismatch": (_ets(chain=[{"transform": "Tz", "joint": "q1"}]),
                          "'chain[0].transform'", None),
    "ets_scale": (_ets(chain=[{"transform": "Rz", "joint": "q1", "scale": 2},
                              {"transform": "Tz", "joint": "q2"}]), "'chain[0].scale'", None),
    "ets_unused_joint": (_ets(chain=[{"transform": "Rz", "joint": "q1"}]), "'chain'", None),
    "ets_bad_role": (_ets(chain=[{"transform": "Rz", "joint": "q1", "role": "magic"},
                                 {"transform": "Tz", "joint": "q2"}]), "'chain[0].role'", None),
    "top_level_list": ("- 1\n- 2\n", "'(top level)'", None),
    "top_level_scalar": ("just text\n", "'(top level)'", None),
    "yaml_syntax": ("name: x\nunits: {length: m, angle: deg\nconvention: standard_dh\n",
                    "line 3 column", None),
    "yaml_tab": ("name: x\n\tunits: 1\n", "line 2 column 1", None),
    "yaml_python_tag": ("name: !!python/object:os.system x\n", "invalid YAML", None),
    "empty": ("", "empty", None),
    "only_comment": ("# nothing here\n", "empty", None),
    "huge_int": ("__HUGE__", "'joints[0].a'", None),
    "int_key_in_row": ("__INTKEY__", "'joints[0].7'", None),
    "int_key_in_base": ("__INTKEY_BASE__", "field 'base.", None),
    "reserved_param_name": (_ets(chain=[{"transform": "Rz", "name": "tool.x", "joint": "q1"},
                                        {"transform": "Tz", "joint": "q2"}]),
                            "'chain[0].name'", None),
    "not_utf8": (b"name: \xff\xfe robot\n", "not_utf8.yaml", None),
}


def _text(name: str, spec: str | bytes | dict) -> str | bytes:
    puma = yaml.safe_dump(_doc(), sort_keys=False)
    if spec == "__NAN__":
        return puma.replace("a: 0.4318", "a: .nan", 1)
    if spec == "__OVERFLOW__":
        return puma.replace("a: 0", "a: 1.0e+999", 1)
    if spec == "__HUGE__":
        return puma.replace("a: 0", f"a: {HUGE}", 1)
    if spec == "__INTKEY__":
        return puma.replace("- name: q1\n", "- name: q1\n  7: 1\n  zz: 2\n", 1)
    if spec == "__INTKEY_BASE__":
        return puma + "base: {x: 0, 1: 0, w: 0}\n"
    if isinstance(spec, dict):
        return yaml.safe_dump(spec, sort_keys=False)
    return spec


# One real ``kincal show`` process per error category (processes are slow to start: the
# full list runs in-process below, through the same ``main()``).
CLI_CASES = ["missing_units", "a_string", "unknown_joint_type", "nan_a", "inf_d",
             "bad_length_unit", "unknown_convention", "duplicate_param_ets", "yaml_syntax",
             "empty", "huge_int", "not_utf8"]


def _write_bad(folder: Path, name: str) -> Path:
    path = folder / f"{name}.yaml"
    text = _text(name, BAD_FILES[name][0])
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def bad_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bad")
    for name in BAD_FILES:
        _write_bad(folder, name)
    return folder


@pytest.fixture(scope="module")
def cli_runs(bad_folder):
    """``kincal show FILE`` as separate processes, two at a time (the machine has 2 cores)."""
    def run(name: str):
        path = bad_folder / f"{name}.yaml"
        p = subprocess.run(
            [sys.executable, "-c", "from kincal.cli import main; main()", "show", str(path)],
            capture_output=True, text=True, errors="replace", timeout=120)
        return name, (path, p.returncode, p.stderr)

    with ThreadPoolExecutor(2) as pool:
        return dict(pool.map(run, CLI_CASES))


def _check_one_line(name: str, path: Path, code: int, stderr: str) -> None:
    assert "Traceback" not in stderr, stderr
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("error: ")
    assert str(path) in lines[0]
    assert BAD_FILES[name][1] in lines[0], lines[0]


def _case(name: str):
    reason = BAD_FILES[name][2]
    marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
    return pytest.param(name, marks=marks, id=name)


@pytest.mark.parametrize("name", [_case(n) for n in CLI_CASES])
def test_bad_file_cli_process(name, cli_runs):
    _check_one_line(name, *cli_runs[name])


@pytest.mark.parametrize("name", [_case(n) for n in BAD_FILES])
def test_bad_file_gives_one_line_naming_file_and_field(name, bad_folder, capsys, monkeypatch):
    from kincal.cli import main

    path = bad_folder / f"{name}.yaml"
    monkeypatch.setattr(sys, "argv", ["kincal", "show", str(path)])
    with pytest.raises(SystemExit) as exc:
        main()                      # any other exception fails the test (a traceback)
    _check_one_line(name, path, exc.value.code, capsys.readouterr().err)


def test_yaml_error_reports_line_and_column(tmp_path):
    path = tmp_path / "r.yaml"
    path.write_text("name: x\nunits: {length: m, angle: deg\nconvention: standard_dh\n")
    with pytest.raises(RobotFileError, match=r"r\.yaml: line 3 column 11: invalid YAML"):
        read_robot_yaml(path)


def test_missing_file_and_unknown_robot(tmp_path):
    with pytest.raises(RobotFileError, match="no such robot file"):
        load_serial_robot(tmp_path / "nothere.yaml")
    with pytest.raises(RobotFileError, match="unknown robot 'puma561'.*puma560"):
        load_serial_robot("puma561")


# --------------------------------------------------------------------------- properties
WORDS = ["name", "description", "source", "units", "length", "angle", "convention", "base",
         "tool", "joints", "chain", "x", "y", "z", "rx", "ry", "rz", "type", "a", "d", "alpha",
         "theta_offset", "beta", "limits", "transform", "value", "joint", "scale", "role",
         "kind", "m", "mm", "rad", "deg", "revolute", "prismatic", "standard_dh",
         "modified_dh", "hayati", "ets", "urdf", "serial", "Rx", "Ry", "Rz", "Tx", "Ty", "Tz",
         "q1", "q2", "offset", "tool.x", "base.rz", "file", ""]
KEYS = st.one_of(st.sampled_from(WORDS), st.text(max_size=4))
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**53), 2**53),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(WORDS), st.text(max_size=6))
DOCS = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(KEYS, inner, max_size=6)), max_leaves=30)
TOP_DOCS = st.one_of(
    DOCS,
    st.fixed_dictionaries({"convention": st.sampled_from(["standard_dh", "modified_dh",
                                                          "hayati", "ets"]),
                           "units": st.one_of(st.just({"length": "m", "angle": "deg"}), DOCS),
                           "joints": DOCS, "chain": DOCS},
                          optional={"base": DOCS, "tool": DOCS, "name": SCALARS}))
SOURCE = "/nonexistent/folder/random.yaml"
PROPS = settings(max_examples=150, deadline=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _only_kincal_errors(doc) -> Robot | None:
    try:
        return robot_from_dict(doc, SOURCE)
    except KincalError as exc:
        assert "\n" not in str(exc)
        return None


@PROPS
@given(doc=TOP_DOCS)
def test_random_documents_raise_only_kincal_error(doc):
    _only_kincal_errors(doc)


@PROPS
@given(text=st.lists(st.sampled_from(list("ab1:-[]{},#&*!|>'\"% \n\t.") + WORDS[:12]),
                     max_size=30).map("".join))
def test_random_yaml_text_raises_only_kincal_error(text):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "r.yaml"
        path.write_text(text, encoding="utf-8")
        try:
            read_robot_yaml(path)
        except KincalError as exc:
            assert "\n" not in str(exc)


def _paths(obj, prefix=()):
    """Every (path, value) inside nested dicts and lists."""
    yield prefix, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


NUMBERS = st.one_of(st.floats(-1e6, 1e6), st.integers(-1000, 1000),
                    st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, -0.0]))
REPLACEMENTS = st.one_of(NUMBERS, SCALARS, DOCS)


@st.composite
def mutated_puma(draw, replacements=REPLACEMENTS):
    doc = copy.deepcopy(PUMA_DOC)
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p, _ in _paths(doc) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        last = path[-1]
        op = draw(st.sampled_from(["replace", "number", "delete", "add", "duplicate"]))
        if op == "replace":
            parent[last] = draw(replacements)
        elif op == "number":
            parent[last] = draw(NUMBERS)
        elif op == "delete":
            del parent[last]
        elif op == "add" and isinstance(parent, dict):
            parent[draw(KEYS)] = draw(replacements)
        elif op == "duplicate" and isinstance(parent, list):
            parent.append(copy.deepcopy(parent[last]))
    return doc


def _check_valid_robot(robot) -> None:
    assert np.isfinite(robot.param_values).all()
    lim = robot.joint_limits
    assert (lim[:, 0] <= lim[:, 1]).all()
    assert not np.isnan(lim).any()
    T = robot.fk(np.zeros(robot.n))
    assert np.isfinite(T).all()
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


@PROPS
@given(doc=mutated_puma())
def test_mutated_puma_documents(doc):
    robot = _only_kincal_errors(doc)
    if robot is not None and isinstance(robot, Robot):
        _check_valid_robot(robot)
        # the valid mutant also survives the YAML text layer and a round trip
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "m.yaml"
            path.write_text(yaml.safe_dump(doc), encoding="utf-8")
            again = read_robot_yaml(path)
            np.testing.assert_array_equal(again.param_values, robot.param_values)
            write_robot_yaml(robot, path)
            np.testing.assert_array_equal(read_robot_yaml(path).param_values,
                                          robot.param_values)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(doc={**PUMA_DOC, "joints": [{**PUMA_DOC["joints"][0], "a": 10**400}]})
@example(doc={**PUMA_DOC, "joints": [{**PUMA_DOC["joints"][0], 3: 1, "w": 2}]})
@given(doc=mutated_puma(st.one_of(REPLACEMENTS, st.integers(), st.dictionaries(
    st.one_of(st.integers(), st.text(max_size=3)), SCALARS, max_size=3))))
def test_documents_with_huge_ints_or_non_string_keys(doc):
    _only_kincal_errors(doc)



@pytest.mark.parametrize("change", [{"units": {"length": "m", "angle": []}},
                                    {"links": {"l1": 10**400, "l2": 0.15, "l3": 0.25,
                                               "l4": 0.25}}], ids=["unhashable_unit", "huge_int"])
def test_fivebar_documents_raise_only_kincal_error(change):
    doc = yaml.safe_load((library_dir() / "fivebar.yaml").read_text())
    doc.update(change)
    with pytest.raises(KincalError):
        robot_from_dict(doc, "fivebar.yaml")
