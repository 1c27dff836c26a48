"""Leftovers of the held-out protocols (issue 26, items 3, 5 and 6).

* the calibrated robot file carries the joint model: ``kincal validate`` with that file
  gives the held-out RMS ``kincal calibrate`` reported (same protocol), to 1e-9 relative;
* ``--select auto`` on multi-placement artifact data (named and numeric placements);
* a negative joint stiffness is refused; the iteration count names its passes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from kincal.cli import app
from kincal.measure.joints.hysteresis import approach_directions

runner = CliRunner()

#: The true hysteresis [rad] of the simulated robot's six joints (a few 0.1 mrad: plays
#: of a worn gearbox), far above what 0.01 mm noise can fake.
TRUE_H = np.array([-4e-4, 3e-4, -3e-4, 2e-4, -2e-4, 1e-4])


def _run(*args: str) -> str:
    res = runner.invoke(app, list(args))
    assert res.exit_code == 0, res.output
    return res.output


def _with_hysteresis(path: Path) -> None:
    """Rewrite a simulated position file as recorded by a robot with play ``TRUE_H``:
    the link sits at the simulated joint values ``q_link``, the encoder reads
    ``q_link - h (.) d`` (d: the direction each joint moved in, from the row order)."""
    lines = path.read_text().splitlines()
    n_head = sum(1 for ln in lines if ln.startswith("#")) + 1
    rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[n_head:]])
    rows[:, :6] -= TRUE_H * approach_directions(rows[:, :6])
    body = [",".join(repr(float(x)) for x in r) for r in rows]
    path.write_text("\n".join(lines[:n_head] + body) + "\n")


@pytest.fixture(scope="module")
def hysteresis_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("hyst")
    _run("simulate", "puma560", "-o", str(d / "train.csv"), "--holdout", str(d / "held.csv"),
         "-n", "80", "--holdout-poses", "40")
    _with_hysteresis(d / "train.csv")
    _with_hysteresis(d / "held.csv")
    return d


@pytest.mark.parametrize("frames", ["training", "register"])
def test_validate_applies_the_joint_model_the_robot_file_carries(hysteresis_data: Path,
                                                                  frames: str) -> None:
    d = hysteresis_data
    cal, res, val = d / f"cal_{frames}.yaml", d / f"res_{frames}.json", d / f"v_{frames}.json"
    _run("calibrate", "puma560", "--data", str(d / "train.csv"), "--validate",
         str(d / "held.csv"), "--joint-model", "hysteresis", "--validation-frames", frames,
         "-o", str(cal), "--json", str(res))
    text = cal.read_text()
    assert "joint_model:" in text
    # the file carries the estimated plays: the simulated ones, within the noise
    from kincal.robots.files import load_serial_robot

    carried = load_serial_robot(str(cal)).meta["joint_model"]
    assert carried["terms"] == ["hysteresis"]
    h = np.array([carried["coefficients"]["tracker"][f"h[q{j}]"] for j in range(1, 7)])
    assert np.allclose(h, TRUE_H, atol=3e-5)
    held = json.loads(res.read_text())["metrics"]["validation"]["rms_position_m"]
    extra = ["--result", str(res)] if frames == "training" else []
    _run("validate", str(cal), "--data", str(d / "held.csv"), "--json", str(val), *extra)
    got = json.loads(val.read_text())["overall"]["rms_position_m"]
    assert got == pytest.approx(held, rel=1e-9)


def test_validate_without_the_joint_model_is_the_geometry_alone(hysteresis_data: Path) -> None:
    """The file without its ``joint_model:`` section is a different model (the geometry
    only): its held-out error is many times the noise, so the section is what matters."""
    d = hysteresis_data
    cal = d / "cal_register.yaml"
    if not cal.exists():
        pytest.skip("runs after the register case")
    import yaml

    doc = yaml.safe_load(cal.read_text())
    doc.pop("joint_model")
    geo = d / "geo.yaml"
    geo.write_text(yaml.safe_dump(doc, sort_keys=False))
    _run("validate", str(geo), "--data", str(d / "held.csv"), "--json", str(d / "g.json"))
    got = json.loads((d / "g.json").read_text())["overall"]["rms_position_m"]
    assert got > 5 * 0.01e-3            # 5 x the simulated noise (0.01 mm)


@pytest.mark.parametrize("labels", [None, ("front_left", "front_right", "back")])
def test_select_auto_splits_artifact_placements_like_cross_validate(
        tmp_path: Path, labels: tuple[str, ...] | None) -> None:
    """Numeric and named placements: ``--select auto`` holds out whole placements, as
    ``--cross-validate`` does, so its geometric candidate (prior x1, the default model)
    has exactly the cross-validated RMS of ``--cross-validate``; the joint-model
    candidates, which cannot wrap artifact constraints, are listed as failed."""
    data = tmp_path / "ts.csv"
    _run("simulate", "puma560", "-i", "two-socket", "-o", str(data), "--placements", "3",
         "-n", "30")
    if labels is not None:
        text = data.read_text()
        for k, name in enumerate(labels, start=1):
            text = text.replace(f"\n{k},", f"\n{name},")
        data.write_text(text)
    _run("calibrate", "puma560", "--data", str(data), "--select", "auto", "--folds", "3",
         "--json", str(tmp_path / "s.json"))
    _run("calibrate", "puma560", "--data", str(data), "--cross-validate", "3",
         "--json", str(tmp_path / "cv.json"))
    sel = json.loads((tmp_path / "s.json").read_text())["selection"]
    cv = json.loads((tmp_path / "cv.json").read_text())["metrics"]["cross_validation"]
    assert cv["split"] == "placements"
    first = sel["candidates"][0]
    assert first["label"] == "geometric, prior x1"
    assert first["rms_coincidence_m"] == pytest.approx(cv["rms_coincidence_m"], rel=1e-9)
    assert sel["chosen"].startswith("geometric")
    hyst = [c for c in sel["candidates"] if c["joint_model"]]
    assert hyst and all(not c["eligible"] and "failed" in c["reason"] for c in hyst)


@pytest.mark.parametrize("k3", [5e-3, -5e-3])
def test_a_negative_joint_stiffness_is_refused(k3: float) -> None:
    """Positions of a PUMA whose joint 3 deflects by ``k3 tau`` (``k3 < 0``: a negative
    stiffness, the joint moving against its load), 0.01 mm noise: the compliance fit
    recovers k3 within its noise, and the verdict refuses exactly the negative one."""
    from test_compliance import INSTRUMENT, MARKERS, PUMA_MASSES

    from kincal.identify.checks import judge
    from kincal.identify.solver import calibrate
    from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
    from kincal.measure.joints.compliance import JointCompliance
    from kincal.measure.simulate import random_configurations
    from kincal.robots.files import load_serial_robot
    from kincal.robots.gravity import gravity_torques

    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    q = random_configurations(robot, 60, rng)
    k = np.array([0.0, 2e-3, k3, 0.0, 0.0, 0.0])
    tau = gravity_torques(robot, q, PUMA_MASSES)
    sim = simulate_positions(robot, q + k * tau, rng, 1e-5, INSTRUMENT, MARKERS)
    inner = PositionMeasurement(q, sim.positions, 1e-5, "tracker", markers=3)
    block = JointCompliance.gravity(inner, robot, PUMA_MASSES, joints=["q2", "q3"])
    res = calibrate(robot, [block], free=["tracker.*"])
    got, std = res.params["tracker.k[q3]"], res.std[list(res.names).index("tracker.k[q3]")]
    assert abs(got - k3) < 5 * std < abs(k3) / 3            # well resolved
    refusals = [r for r in judge(res, {}).refusals if r.kind == "compliance"]
    if k3 < 0:
        assert len(refusals) == 1 and "tracker.k[q3]" in refusals[0].sentence
        assert "negative joint stiffness" in refusals[0].sentence
    else:
        assert not refusals


def test_the_iteration_count_names_its_passes(hysteresis_data: Path) -> None:
    """The iterations add up over passes (the noise-scale re-solve is one): the console
    says over how many, as the history (the convergence plot's data) counts them."""
    d = hysteresis_data
    out = _run("calibrate", "puma560", "--data", str(d / "train.csv"), "--joint-model",
               "hysteresis", "--json", str(d / "it.json"))
    doc = json.loads((d / "it.json").read_text())
    starts = [h for h in doc["history"] if h["iteration"] == 0]
    assert doc["passes"] == len(starts) >= 2
    assert doc["iterations"] == sum(1 for h in doc["history"] if h["iteration"] > 0)
    assert f"in {doc['iterations']} iterations over {doc['passes']} passes" in out


TIAGO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "tiago_mocap"
TIAGO_SETUP = Path(__file__).resolve().parents[1] / "examples" / "setups" / "tiago_mocap.yaml"


def test_the_real_tiago_compliance_model_gives_the_same_number_in_validate(
        tmp_path: Path) -> None:
    """Both terms on the real TIAGo (the loads need the URDF's masses): validate with the
    written YAML gives calibrate's held-out RMS exactly; with the written URDF (origins
    as URDF text) to the URDF's rounding."""
    if not (TIAGO / "validation_2021-11-26.csv").is_file():
        pytest.skip("the TIAGo data set is not in ../shared/data")
    held = tmp_path / "held.csv"          # the held-out file, named as in the setup file
    held.write_text("# kincal measurements: instrument=position; name=mocap; sigma=1mm\n"
                    + (TIAGO / "validation_2021-11-26.csv").read_text())
    cal, urdf, res = tmp_path / "t.yaml", tmp_path / "t.urdf", tmp_path / "t.json"
    _run("calibrate", "--config", str(TIAGO_SETUP), "-o", str(cal), "--urdf", str(urdf),
         "--json", str(res), "--report", str(tmp_path / "t.html"))
    want = json.loads(res.read_text())["metrics"]["validation"]["rms_position_m"]
    for robot, rel in ((cal, 1e-9), (urdf, 1e-5)):
        _run("validate", str(robot), "--tip-link", "wrist_ft_tool_link", "--data", str(held),
             "--units", "x?=m,y?=m,z?=m", "--result", str(res), "--json", str(tmp_path / "v.json"))
        got = json.loads((tmp_path / "v.json").read_text())["overall"]["rms_position_m"]
        assert got == pytest.approx(want, rel=rel), robot.name


def test_iso9283_with_a_joint_model_prints_each_warning_once(hysteresis_data: Path,
                                                              tmp_path: Path) -> None:
    """``validate --iso9283`` with a robot file that carries a joint model: the figures
    come (exit 0), and the outside-the-region warning is one line, not repeated as a
    Python UserWarning on stderr (``> log 2>&1`` showed both)."""
    import subprocess
    import sys

    d = hysteresis_data
    lines = (d / "held.csv").read_text().splitlines()
    n_head = sum(1 for ln in lines if ln.startswith("#")) + 1
    cycles = tmp_path / "cycles.csv"          # 6 positions, 3 cycles each
    cycles.write_text("\n".join(lines[:n_head] + [lines[n_head + i] for _ in range(3)
                                                  for i in range(6)]) + "\n")
    cal, res = d / "cal_iso.yaml", d / "res_iso.json"
    _run("calibrate", "puma560", "--data", str(d / "train.csv"), "--joint-model",
         "hysteresis", "-o", str(cal), "--json", str(res))
    for extra in ([], ["--result", str(res)]):
        run = subprocess.run([sys.executable, "-c", "from kincal.cli import main; main()",
                              "validate", str(cal), "--data", str(cycles), "--iso9283", *extra],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert run.returncode == 0, run.stdout
        assert "ISO 9283 on cycles.csv" in run.stdout
        assert "UserWarning" not in run.stdout
        assert run.stdout.count("lie outside the training region") == 1
