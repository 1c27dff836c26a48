"""The calibrated robot carries its envelope (training region, accuracy model, data, date,
version), every command that takes it uses it, and the nominal robot's predicted error is
its tolerances propagated (checked by Monte Carlo against perturbed robots)."""

from __future__ import annotations

import csv
import hashlib
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import run

from kincal.errors import KincalError
from kincal.identify.accuracy import AccuracyModel, nominal_spread
from kincal.identify.envelope import (
    Envelope,
    envelope_of,
    predict_with_envelope,
    with_envelope,
)
from kincal.identify.validation import validate
from kincal.measure.instruments.position import simulate_positions
from kincal.robots.files import envelope_sidecar, load_serial_robot, robot_yaml_text
from kincal.workflow.robots import load_any_robot
from kincal.workflow.validation import validate_on_files

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "motoman_leica"
GRID = DATA / "right_arm_grid_6x6x6.csv"
JOINTS = ["E_rad", "S_rad", "L_rad", "U_rad", "R_rad", "B_rad", "T_rad"]
needs_data = pytest.mark.skipif(not GRID.is_file(), reason="shared Motoman data not present")


def _split(tmp: Path) -> tuple[Path, Path]:
    """The grid's inner part (every moving joint within the middle 60 % of its range) and
    the rest, as two CSV files."""
    with open(GRID, newline="") as f:
        rows = list(csv.DictReader(f))
    Q = np.array([[float(r[c]) for c in JOINTS] for r in rows])
    lo, hi = Q.min(axis=0), Q.max(axis=0)
    span = hi - lo
    inner = np.all(((Q >= lo + 0.2 * span) & (Q <= hi - 0.2 * span)) | (span < 1e-3), axis=1)
    paths = []
    for name, mask in (("inner", inner), ("outer", ~inner)):
        p = tmp / f"{name}.csv"
        with open(p, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(r for r, m in zip(rows, mask, strict=True) if m)
        paths.append(p)
    return paths[0], paths[1]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``kincal calibrate`` on the grid's inner part: YAML, URDF (+ sidecar) and JSON."""
    if not GRID.is_file():
        pytest.skip("shared Motoman data not present")
    tmp = tmp_path_factory.mktemp("envelope")
    inner, outer = _split(tmp)
    files = {"inner": inner, "outer": outer, "yaml": tmp / "cal.yaml",
             "urdf": tmp / "cal.urdf", "json": tmp / "cal.json"}
    from cli_helpers import invoke

    code = invoke("calibrate", "motoman_right", "--data", inner, "-o", files["yaml"],
                  "--urdf", files["urdf"], "--json", files["json"])
    assert code == 0
    return files


# --------------------------------------------------------------------------- round trip
@needs_data
def test_written_robot_carries_its_envelope(calibrated: dict[str, Path]) -> None:
    doc = yaml.safe_load(calibrated["yaml"].read_text())
    sec = doc["calibration"]
    digest = hashlib.sha256(calibrated["inner"].read_bytes()).hexdigest()
    assert sec["data"] == [{"file": "inner.csv", "sha256": digest, "rows": 65}]
    assert sec["kincal_version"]
    assert sec["created"][:4].isdigit()
    acc = sec["accuracy_model"]
    # the training joint ranges are those of the training file
    with open(calibrated["inner"], newline="") as f:
        Q = np.array([[float(r[c]) for c in JOINTS] for r in csv.DictReader(f)])
    np.testing.assert_array_equal(acc["joint_min"], Q.min(axis=0))
    np.testing.assert_array_equal(acc["joint_max"], Q.max(axis=0))
    assert acc["hull_m"] is not None and acc["floor_m"] > 0
    assert acc["tolerances"]["a[2]"] == pytest.approx(1e-3)
    # the same envelope in the result JSON
    import json

    assert json.loads(calibrated["json"].read_text())["envelope"]["data"] == sec["data"]


@needs_data
def test_envelope_reads_back_identically(calibrated: dict[str, Path], tmp_path: Path) -> None:
    robot = load_any_robot(calibrated["yaml"])
    env = envelope_of(robot)
    assert env is not None
    again = Envelope.from_dict(yaml.safe_load(yaml.safe_dump(env.to_dict())), "x")
    assert again.to_dict() == env.to_dict()
    # written and read once more: the same section
    out = tmp_path / "again.yaml"
    out.write_text(robot_yaml_text(robot))
    env2 = envelope_of(load_any_robot(out))
    assert env2 is not None and env2.to_dict() == env.to_dict()
    reg, reg2 = env.accuracy.region, env2.accuracy.region
    assert reg is not None and reg2 is not None and reg2.hull is not None
    np.testing.assert_array_equal(reg.hull, reg2.hull)
    np.testing.assert_array_equal(env.accuracy.covariance, env2.accuracy.covariance)


def test_old_robot_files_load_without_an_envelope(tmp_path: Path) -> None:
    robot = load_any_robot("puma560")
    assert envelope_of(robot) is None
    p = tmp_path / "old.yaml"
    p.write_text(robot_yaml_text(robot))
    assert "calibration" not in yaml.safe_load(p.read_text())
    assert envelope_of(load_any_robot(p)) is None
    assert predict_with_envelope(load_any_robot(p), np.zeros((1, 6))) is None


@needs_data
@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(calibration="nothing"), "calibration"),
    (lambda d: d["calibration"].update(format=7), "has format 7"),
    (lambda d: d["calibration"]["accuracy_model"].update(covariance=[[1.0]]),
     "accuracy_model is not readable"),
    (lambda d: d["calibration"]["accuracy_model"].update(joint_min=[0.0]),
     "unreadable joint ranges"),
    (lambda d: d["calibration"].pop("robot"), "not readable"),
    (lambda d: d["joints"][2].update(a=d["joints"][2]["a"] + 1e-3), "does not match"),
])
def test_corrupted_or_mismatched_section_is_one_line(calibrated: dict[str, Path],
                                                     tmp_path: Path, capsys, edit,
                                                     words: str) -> None:
    doc = yaml.safe_load(calibrated["yaml"].read_text())
    edit(doc)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(KincalError, match=words) as exc:
        load_any_robot(bad)
    assert "\n" not in str(exc.value) and str(bad) in str(exc.value)
    code, out, err = run(capsys, "fk", bad, "--q", "0,0,0,0,0,0,0")
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err.replace("\n", "")


# --------------------------------------------------------------------------- URDF
@needs_data
def test_urdf_stays_standard_and_its_sidecar_travels(calibrated: dict[str, Path],
                                                    tmp_path: Path, capsys) -> None:
    urdf = calibrated["urdf"]
    root = ET.parse(urdf).getroot()              # valid XML
    standard = {"robot", "link", "joint", "origin", "axis", "parent", "child", "limit",
                "inertial", "mass", "inertia", "visual", "collision", "geometry",
                "material", "dynamics", "mimic", "safety_controller", "calibration"}
    assert root.tag == "robot"
    assert {e.tag for e in root.iter()} <= standard
    assert envelope_sidecar(urdf).is_file()
    try:
        import yourdfpy  # the oracle, when installed

        yourdfpy.URDF.load(str(urdf), load_meshes=False)
    except ImportError:
        pass
    from_urdf, from_yaml = load_any_robot(urdf), load_any_robot(calibrated["yaml"])
    q = np.loadtxt(calibrated["outer"], delimiter=",", skiprows=1, usecols=range(1, 8))
    a, b = predict_with_envelope(from_urdf, q), predict_with_envelope(from_yaml, q)
    assert a is not None and b is not None
    np.testing.assert_allclose(a.predicted_m, b.predicted_m, rtol=1e-9)
    # `kincal export` to a URDF writes the sidecar too; back to YAML keeps the section
    code, out, _ = run(capsys, "export", calibrated["yaml"], "-o", tmp_path / "e.urdf")
    assert code == 0 and "calibration envelope" in out
    assert (tmp_path / "e.envelope.yaml").is_file()
    code, _, _ = run(capsys, "export", tmp_path / "e.urdf", "-o", tmp_path / "e.yaml",
                     "--as-ets")
    assert code == 0 and envelope_of(load_any_robot(tmp_path / "e.yaml")) is not None


# --------------------------------------------------------------------------- use
@needs_data
def test_validate_with_only_the_robot_file_warns(calibrated: dict[str, Path],
                                                 capsys) -> None:
    code, out, _ = run(capsys, "validate", calibrated["yaml"], "--data", calibrated["outer"],
                       "--before", "motoman_right")
    text = " ".join(out.split())
    assert code == 0
    assert "warning: outer.csv: 147 of 147 poses lie outside the training region" in text
    code, out, _ = run(capsys, "validate", calibrated["yaml"], "--data", calibrated["inner"])
    assert code == 0 and "warning" not in out and "65 of 65 poses inside" in " ".join(
        out.split())
    # the nominal robot has no envelope: no prediction, no warning
    code, out, _ = run(capsys, "validate", "motoman_right", "--data", calibrated["outer"])
    assert code == 0 and "warning" not in out


@needs_data
def test_library_validation_uses_the_envelope(calibrated: dict[str, Path]) -> None:
    import kincal

    robot = kincal.load_robot(calibrated["yaml"])
    blocks = kincal.read_measurements(calibrated["outer"], robot)
    val = validate_on_files(robot, [blocks] if not isinstance(blocks, list) else blocks)
    assert val.accuracy_from == "robot" and len(val.warnings) == 1
    with pytest.warns(UserWarning, match="outside the training region"):
        doc = validate(robot, blocks)
    assert doc["warnings"] and all(p.outside.all() for p in doc["predicted"].values())


@needs_data
def test_fk_and_ik_say_when_outside(calibrated: dict[str, Path], capsys) -> None:
    with open(calibrated["inner"], newline="") as f:
        q_in = [r for r in csv.DictReader(f)][0]
    with open(calibrated["outer"], newline="") as f:
        q_out = [r for r in csv.DictReader(f)][0]
    inside = ",".join(q_in[c] for c in JOINTS)
    outside = ",".join(q_out[c] for c in JOINTS)
    code, out, _ = run(capsys, "fk", calibrated["yaml"], "--q", inside)
    assert code == 0 and "predicted error (calibration envelope)" in out
    assert "warning" not in out
    code, out, _ = run(capsys, "fk", calibrated["yaml"], "--q", outside)
    assert code == 0 and "lie outside the training region" in " ".join(out.split())
    code, out, _ = run(capsys, "fk", "motoman_right", "--q", outside)
    assert code == 0 and "calibration envelope" not in out


# --------------------------------------------------------------------------- nominal
def _toleranced(robot) -> dict[str, float]:
    tol = {"a": 1e-3, "d": 1e-3, "alpha": math.radians(0.1), "theta_offset": math.radians(0.5)}
    return {n: tol[n.split("[")[0]] for n in robot.param_names if n.split("[")[0] in tol}


def _model(robot, point) -> AccuracyModel:
    return AccuracyModel((), np.zeros((0, 0)), np.asarray(point, float),
                         tolerances=_toleranced(robot))


def test_nominal_spread_is_the_tolerances_propagated() -> None:
    """Monte Carlo: robots whose parameters lie about the nominal ones by their tolerances;
    the RMS distance of their tool point from the nominal one's is the predicted spread."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    q = rng.uniform(-1.0, 1.0, (6, nominal.n))
    point = np.array([0.0, 0.0, 0.1])
    spread = nominal_spread(_model(nominal, point), nominal, q, point)
    assert spread is not None
    tols = _toleranced(nominal)
    idx = nominal.param_indices(list(tols))
    s = np.array(list(tols.values()))
    T0 = nominal.fk(q)
    P0 = T0[:, :3, 3] + T0[:, :3, :3] @ point
    sq = np.zeros(len(q))
    n = 3000
    for _ in range(n):
        p = np.array(nominal.param_values, dtype=float)
        p[idx] += s * rng.standard_normal(len(s))
        T = nominal.with_params(p).fk(q)
        sq += np.sum((T[:, :3, 3] + T[:, :3, :3] @ point - P0) ** 2, axis=1)
    mc = np.sqrt(sq / n)
    # the RMS of a sum of 3 squared normals over n draws: relative error ~ 1/sqrt(2n)
    np.testing.assert_allclose(spread, mc, rtol=0.06)


def test_nominal_spread_registered_matches_refitting_the_instrument() -> None:
    """With the instrument registered to the nominal robot on the same configurations, the
    predicted spread equals the RMS residual of that (nonlinear) registration over robots
    drawn from the tolerances."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, (25, nominal.n))
    frame = np.array([1.0, 0.3, -0.2, 0.2, -0.1, 0.3])
    marker = np.array([0.02, -0.01, 0.08])
    inst = {"block": "tracker", "nominal_values": [*frame, *marker]}
    spread = nominal_spread(_model(nominal, marker), nominal, q, marker, inst)
    assert spread is not None
    tols = _toleranced(nominal)
    idx = nominal.param_indices(list(tols))
    s = np.array(list(tols.values()))
    sums = []
    for _ in range(150):
        p = np.array(nominal.param_values, dtype=float)
        p[idx] += s * rng.standard_normal(len(s))
        block = simulate_positions(nominal.with_params(p), q, None, 0.0, frame, marker)
        fitted = validate(nominal, [block])["extras"]["tracker"]
        e = block.errors(nominal, np.array(list(fitted.values())))["position_m"]
        sums.append(float(np.sum(np.asarray(e) ** 2)))
    predicted = float(np.sum(spread**2))
    # the sum of squared residuals is a weighted chi-square: its mean over the draws is
    # known to 4 standard errors, from the draws themselves
    assert abs(np.mean(sums) - predicted) < 4.0 * np.std(sums) / math.sqrt(len(sums))


@needs_data
def test_nominal_predicted_error_is_sane_on_motoman(calibrated: dict[str, Path]) -> None:
    """It was 1.22e3 mm far from the data (the calibration's correction, extrapolated); it
    is now the tolerances propagated: a few millimetres on a 1.5 m arm."""
    robot = load_any_robot(calibrated["yaml"])
    nominal = load_any_robot("motoman_right")
    q = np.loadtxt(calibrated["outer"], delimiter=",", skiprows=1, usecols=range(1, 8))
    pred = predict_with_envelope(robot, q, nominal=nominal)
    assert pred is not None and pred.nominal_predicted_m is not None
    assert np.all(np.isfinite(pred.nominal_predicted_m))
    assert 1e-4 < pred.nominal_predicted_m.max() < 0.02


def test_with_envelope_none_strips_the_section() -> None:
    robot = load_serial_robot("puma560")
    fake = with_envelope(robot, None)
    assert "calibration" not in fake.meta


# --------------------------------------------------------------------------- UR, URDF robots
def test_ur_kinematics_and_urdf_robots_carry_it(tmp_path: Path, capsys) -> None:
    """A calibrated UR written as the ROS kinematics YAML has its envelope next to it, and
    `kincal import ur` reads it back; a URDF robot's calibrated URDF likewise."""
    code, _, _ = run(capsys, "simulate", "ur5e", "-o", tmp_path / "d.csv", "-n", "40",
                     "--noise", "0.01mm", "--seed", "3")
    assert code == 0
    cal = tmp_path / "cal.yaml"
    assert run(capsys, "calibrate", "ur5e", "--data", tmp_path / "d.csv", "-o", cal)[0] == 0
    kin = tmp_path / "kin.yaml"
    code, out, _ = run(capsys, "ur-kinematics", cal, "--nominal", "ur5e", "-o", kin)
    assert code == 0 and (tmp_path / "kin.envelope.yaml").is_file()
    back = tmp_path / "back.yaml"
    assert run(capsys, "import", "ur", kin, "--nominal", "ur5e", "-o", back)[0] == 0
    env, env0 = envelope_of(load_any_robot(back)), envelope_of(load_any_robot(cal))
    assert env is not None and env0 is not None and env.to_dict() == env0.to_dict()

    urdf_in = Path(__file__).resolve().parents[1] / "examples" / "tutorials" / "files" / \
        "arm.urdf"
    code, _, _ = run(capsys, "simulate", urdf_in, "--tip-link", "tool0", "-o",
                     tmp_path / "arm.csv", "-n", "40", "--noise", "0.01mm", "--seed", "2")
    assert code == 0
    out_urdf = tmp_path / "arm_cal.urdf"
    code, _, _ = run(capsys, "calibrate", urdf_in, "--tip-link", "tool0", "--data",
                     tmp_path / "arm.csv", "-o", tmp_path / "arm_cal.yaml", "--urdf", out_urdf)
    assert code == 0
    robot = load_any_robot(out_urdf, tip_link="tool0")
    assert envelope_of(robot) is not None
    assert "envelope" not in out_urdf.read_text()       # the URDF itself stays plain


@needs_data
def test_compensate_uses_the_envelope(calibrated: dict[str, Path], tmp_path: Path,
                                      capsys) -> None:
    robot = load_any_robot(calibrated["yaml"])
    for name, expect in (("inner", False), ("outer", True)):
        q = np.loadtxt(calibrated[name], delimiter=",", skiprows=1, usecols=range(1, 8))[:5]
        p = robot.fk(q)[:, :3, 3]
        t = tmp_path / f"t_{name}.csv"
        rows = [",".join(repr(float(v)) for v in [*qi, *pi]) for qi, pi in
                zip(q, p, strict=True)]
        t.write_text("\n".join([",".join([*JOINTS, "x_m", "y_m", "z_m"]), *rows]) + "\n")
        code, out, _ = run(capsys, "compensate", calibrated["yaml"], "--targets", t, "-o",
                           tmp_path / f"j_{name}.csv")
        text = " ".join(out.split())
        assert code == 0 and "predicted:" in text
        assert ("5 of 5 targets lie outside the training region" in text) is expect


@needs_data
def test_plan_on_a_calibrated_robot_says_where_it_leaves_the_region(
        calibrated: dict[str, Path], tmp_path: Path, capsys) -> None:
    code, out, _ = run(capsys, "plan", calibrated["yaml"], "-o", tmp_path / "p.csv",
                       "--poses", "12")
    assert code == 0 and "planned poses lie outside the training region" in " ".join(
        out.split())


@needs_data
def test_changed_parameters_drop_the_envelope(calibrated: dict[str, Path]) -> None:
    robot = load_any_robot(calibrated["yaml"])
    assert "calibration" in robot.with_params(robot.param_values).meta
    moved = robot.with_params({"a[2]": robot.params()["a[2]"] + 1e-3})
    assert "calibration" not in moved.meta and envelope_of(moved) is None
