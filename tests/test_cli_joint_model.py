"""``--joint-model`` end to end: a simulated PUMA 560 whose joints have play, measured in
the order of its postures, calibrated and validated from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run, write_tracker
from test_compliance import perturbed_puma

from kincal.measure.instruments.position import simulate_positions
from kincal.measure.joints.hysteresis import approach_directions
from kincal.measure.simulate import random_configurations
from kincal.robots.files import load_serial_robot

NOISE = 20e-6                                                    # m per coordinate
H_TRUE = np.array([-1.5e-3, -4e-3, -2.5e-3, -6e-3, -3e-3, -8e-3])  # rad, the play (lag)
INSTRUMENT = [1.4, -0.6, 0.3, 2.1, -0.3, 0.2]
MARKER = np.array([[0.05, 0.0, 0.1]])


def _session(path, true, q, rng):
    """A tracker file of the true robot with play, rows in the order measured."""
    sim = simulate_positions(true, q + H_TRUE * approach_directions(q), rng, NOISE,
                             INSTRUMENT, MARKER)
    write_tracker(path, true, q, sim.positions)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("play")
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(21)
    true = perturbed_puma(nominal, rng)
    _session(d / "train.csv", true, random_configurations(nominal, 80, rng), rng)
    _session(d / "hold.csv", true, random_configurations(nominal, 40, rng), rng)
    return d


def _calibrate(capsys, d, *extra):
    code, out, err = run(capsys, "calibrate", "puma560", "--data", d / "train.csv",
                         "--validate", d / "hold.csv", "-o", d / "cal.yaml",
                         "--json", d / "res.json", *extra)
    assert code == 0, err
    return out, json.loads((d / "res.json").read_text())


def test_hysteresis_is_recovered_and_validates_at_the_noise(capsys, files):
    out, doc = _calibrate(capsys, files, "--joint-model", "hysteresis")
    assert "joint model: hysteresis" in out
    par = {p["name"]: p for p in doc["parameters"]}
    for j, h in enumerate(H_TRUE, start=1):
        p = par[f"tracker.h[q{j}]"]
        assert p["identifiable"] and abs(p["estimate"] - h) < 4 * p["std"], (j, p)
    # held-out RMS of the 3-D error: sqrt(3) x the per-coordinate noise (+ a little for
    # the parameters' uncertainty); without the joint model the play is left over
    v = doc["metrics"]["validation"]["rms_position_m"]
    assert v < 1.3 * np.sqrt(3) * NOISE, v
    _, plain = _calibrate(capsys, files)
    assert plain["metrics"]["validation"]["rms_position_m"] > 5 * v
    assert not any(".h[" in p["name"] for p in plain["parameters"])


def test_validate_uses_the_calibrated_joint_model(capsys, files):
    _calibrate(capsys, files, "--joint-model", "hysteresis")
    args = ["validate", files / "cal.yaml", "--data", files / "hold.csv", "--result",
            files / "res.json", "--json", files / "val.json"]
    code, _, err = run(capsys, *args, "--joint-model", "hysteresis")
    assert code == 0, err
    with_model = json.loads((files / "val.json").read_text())["overall"]["rms_position_m"]
    code, _, err = run(capsys, *args)              # the joint model the robot file carries
    assert code == 0, err
    carried = json.loads((files / "val.json").read_text())["overall"]["rms_position_m"]
    assert carried == pytest.approx(with_model, rel=1e-9)
    import yaml

    doc = yaml.safe_load((files / "cal.yaml").read_text())
    assert doc.pop("joint_model", None) is not None
    (files / "geometry.yaml").write_text(yaml.safe_dump(doc))
    code, _, err = run(capsys, "validate", files / "geometry.yaml", *args[2:])
    assert code == 0, err
    without = json.loads((files / "val.json").read_text())["overall"]["rms_position_m"]
    assert with_model < 1.3 * np.sqrt(3) * NOISE < without / 5, (with_model, without)


@pytest.mark.parametrize(("args", "message"), [
    (["--joint-model", "backlash"], "option --joint-model: unknown term 'backlash'"),
    (["--joint-model", "hysteresis,hysteresis"], "listed twice"),
    (["--joint-model", "compliance"], "'puma560' states none"),
])
def test_bad_joint_model_is_one_line(capsys, files, args, message):
    out_file = files / "bad.yaml"
    code, out, err = run(capsys, "calibrate", "puma560", "--data", files / "train.csv",
                         "-o", out_file, *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not out_file.exists()


def test_validate_needs_the_result_for_a_joint_model(capsys, files):
    code, _, err = run(capsys, "validate", "puma560", "--data", files / "hold.csv",
                       "--joint-model", "hysteresis")
    assert code == 2 and "--joint-model needs --result" in err


TIAGO = Path(__file__).resolve().parents[2] / "shared" / "data" / "tiago_mocap"


@pytest.mark.skipif(not TIAGO.is_dir(), reason=f"real TIAGo data not found at {TIAGO}")
def test_tiago_from_the_command_line(capsys, tmp_path):
    """The leave-one-out choice of test_real_tiago (least squares + gravity compliance +
    hysteresis, all four markers) from the command line: the same 56 parameters and the
    same arm_6 play as the library call.  Least squares moves arm_5's origin by more than
    10 tolerances (10 mm): the command says so and exits 1 (``--force`` still writes the
    robot)."""
    code, out, err = run(
        capsys, "calibrate", TIAGO / "tiago_48_schunk.urdf", "--tip-link", "wrist_ft_tool_link",
        "--data", TIAGO / "train_2021-11-30.csv", "--validate",
        TIAGO / "validation_2021-11-26.csv", "--validation-frames", "training",
        "--units", "x?=m,y?=m,z?=m,torso_lift_joint=m,arm_?_joint=rad",
        "--ignore", "shipped_row,t_start_robot,t_end_robot,marker_std_mm",
        "--joint-model", "hysteresis,compliance", "-o", tmp_path / "cal.yaml",
        "--json", tmp_path / "res.json", "--force", "--prior", "none")
    assert code == 1 and "arm_5_joint.origin.x moved" in err, err
    assert (tmp_path / "cal.yaml").is_file()
    doc = json.loads((tmp_path / "res.json").read_text())
    par = {p["name"]: p for p in doc["parameters"]}
    assert doc["identifiable_count"] == 56
    # the file names no instrument: its block (and the joint terms around it) is "instrument"
    h6, k6 = par["instrument.h[arm_6_joint]"], par["instrument.k[arm_6_joint]"]
    assert h6["estimate"] == pytest.approx(-5.8e-3, abs=0.1e-3), h6
    assert h6["std"] == pytest.approx(0.6e-3, abs=0.1e-3), h6
    assert 0.02 < k6["estimate"] < 0.03 and k6["std"] < 0.003, k6
    assert not par["instrument.k[arm_1_joint]"]["identifiable"]
    m = doc["metrics"]
    print(f"\nTIAGo CLI, all four markers, hysteresis + compliance: train "
          f"{m['train']['rms_position_m'] * 1e3:.3f} mm, validation "
          f"{m['validation']['rms_position_m'] * 1e3:.3f} mm")
    assert m["validation"]["rms_position_m"] < 3.2e-3


@pytest.mark.skipif(not TIAGO.is_dir(), reason=f"real TIAGo data not found at {TIAGO}")
def test_prior_is_weighed_with_the_estimated_noise_scale(capsys, tmp_path):
    """The TIAGo files have no sigma column, so the 10 um default applies while the
    residuals are millimetres.  The noise scale is estimated before the prior is weighed
    (sigma0 ~ 100), so the default prior holds the origins (a trusted calibration, exit
    0) instead of letting them follow the noise by 13 mm and 6 deg, as a prior weighed
    with the stated 10 um does (``calibrate(..., noise_scale=1)``)."""
    code, out, err = run(
        capsys, "calibrate", TIAGO / "tiago_48_schunk.urdf", "--tip-link", "wrist_ft_tool_link",
        "--data", TIAGO / "train_2021-11-30.csv", "--units",
        "x1=m,y1=m,z1=m,torso_lift_joint=m,arm_?_joint=rad", "--ignore",
        "x2,y2,z2,x3,y3,z3,x4,y4,z4,shipped_row,t_start_robot,t_end_robot,marker_std_mm",
        "--json", tmp_path / "res.json")
    assert code == 0, err
    doc = json.loads((tmp_path / "res.json").read_text())
    assert 60 < doc["sigma0"] < 200 and doc["verdict"]["trusted"]
    text = " ".join(out.split())
    assert "estimated before the prior was weighed" in text
    moved = max(abs(p["estimate"] - p["nominal"]) / p["prior_std"]
                for p in doc["parameters"] if p["estimated"] and p["prior_std"])
    assert moved < 5, moved
    # the parameters the prior holds are named, with what would identify them
    assert doc["held_by_prior"] and "weak" in out
    assert all("held by the prior" in w["sentence"] for w in doc["held_by_prior"])


def test_cross_validation_compares_models_on_training_alone(capsys, files):
    """--cross-validate K: the held-out-fold RMS of each model, from the training file;
    the model with the play predicts at the noise floor, the geometric one does not."""
    cv = {}
    for jm in ([], ["--joint-model", "hysteresis"]):
        out, doc = _calibrate(capsys, files, "--cross-validate", "5", *jm)
        c = doc["metrics"]["cross_validation"]
        assert c["folds"] == 5 and c["seed"] == 0 and c["split"] == "rows"
        assert "5-fold cross-validation on the training file" in " ".join(out.split())
        cv[bool(jm)] = c["rms_position_m"]
    assert cv[True] < 1.3 * np.sqrt(3) * NOISE < cv[False] / 5, cv


@pytest.mark.parametrize(("args", "message"), [
    (["--cross-validate", "1"], "needs at least 2 folds"),
    (["--cross-validate", "3", "--procedure", "staged-selection"], "works with --procedure lm"),
])
def test_bad_cross_validation_is_one_line(capsys, files, args, message):
    code, _, err = run(capsys, "calibrate", "puma560", "--data", files / "train.csv",
                       "-o", files / "bad.yaml", *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (files / "bad.yaml").exists()


def test_cross_validation_of_two_training_files(capsys, files, tmp_path):
    """Each fold holds out a part of every training file (fused calibration)."""
    j = tmp_path / "two.json"
    code, _, err = run(capsys, "calibrate", "puma560", "--data", files / "train.csv",
                       "--data", files / "hold.csv", "--cross-validate", "3", "--json", j)
    assert code == 0, err
    c = json.loads(j.read_text())["metrics"]["cross_validation"]
    assert c["folds"] == 3 and c["split"] == "rows" and c["rms_position_m"] > 0
