"""The calibration commands end to end: simulate -> calibrate -> validate -> compensate.

Truth is independent of the solver: the simulated true robot is written to a YAML
file by ``kincal simulate`` and compared, through forward kinematics of the written
files, with the calibrated YAML on held-out configurations.
"""

from __future__ import annotations

import base64
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import invoke, run

from kincal.errors import MeasurementFileError
from kincal.measure.registry import instruments, read_measurements
from kincal.robots.files import load_serial_robot

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")

NOISE = 1e-5   # m, per coordinate, used throughout



@pytest.fixture(scope="module")
def flow(tmp_path_factory):
    """simulate -> calibrate (with validation, JSON, report) once for several tests."""
    d = tmp_path_factory.mktemp("flow")
    files = {k: d / v for k, v in (("train", "train.csv"), ("hold", "hold.csv"),
                                   ("truth", "truth.yaml"), ("sim", "sim.json"),
                                   ("cal", "cal.yaml"), ("res", "res.json"),
                                   ("rep", "report.html"))}
    args_sim = ["simulate", "puma560", "-o", files["train"], "--truth", files["truth"],
                "--poses", "60", "--noise", f"{NOISE * 1e3!r}mm", "--seed", "5",
                "--holdout", files["hold"], "--holdout-poses", "40", "--length-unit", "mm",
                "--angle-unit", "deg", "--json", files["sim"]]
    args_cal = ["calibrate", "puma560", "--data", files["train"], "--validate", files["hold"],
                "-o", files["cal"], "--json", files["res"], "--report", files["rep"],
                "--stages", "offsets,all", "--truth", files["truth"]]
    for key, args in (("sim", args_sim), ("cal", args_cal)):
        assert invoke(*args) == 0, f"{key} failed"
    return files


def _kabsch_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance between point sets after the best rigid alignment of a onto b."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return float(np.sqrt(np.mean(np.sum((a - ca) @ R.T + cb - b, axis=1) ** 2)))


def test_simulate_calibrate_recovers_the_truth(flow):
    """The written calibrated YAML predicts the measured point like the truth YAML does,
    on held-out configurations, up to the rigid frame the data cannot see (the robot's
    base and joint-1 zero are absorbed by the unknown tracker frame)."""
    truth, cal, nominal = (load_serial_robot(flow[k]) if k != "nom"
                           else load_serial_robot("puma560") for k in ("truth", "cal", "nom"))
    sim = json.loads(flow["sim"].read_text())
    res = json.loads(flow["res"].read_text())
    est = {p["name"]: p["estimate"] for p in res["parameters"]}
    m_true = np.array([sim["instrument_truth"][f"tracker.marker.{c}"] for c in "xyz"])
    m_cal = np.array([est[f"tracker.marker.{c}"] for c in "xyz"])
    q = read_measurements(flow["hold"], nominal)[0].q

    def point(robot, m):
        T = robot.fk(q)
        return T[:, :3, 3] + T[:, :3, :3] @ m

    after = _kabsch_rms(point(cal, m_cal), point(truth, m_true))
    before = _kabsch_rms(point(nominal, m_cal), point(truth, m_true))
    # at the noise level: well below the per-coordinate noise times sqrt(3)
    assert after < NOISE * math.sqrt(3)
    assert before > 50 * after
    # the held-out residuals (noisy measurements) sit at the noise level too
    v = res["metrics"]["validation"]
    assert v["rms_position_m"] == pytest.approx(NOISE * math.sqrt(3), rel=0.3)
    assert v["before"]["rms_position_m"] > 20 * v["rms_position_m"]


def test_result_json_has_the_required_keys(flow):
    res = json.loads(flow["res"].read_text())
    for key in ("parameters", "identifiable_count", "converged", "iterations", "metrics"):
        assert key in res
    assert res["converged"] is True and res["iterations"] > 0
    p = res["parameters"][0]
    assert {"name", "nominal", "estimate", "std", "identifiable"} <= set(p)
    assert res["identifiable_count"] == sum(q["identifiable"] for q in res["parameters"])
    for split in ("train", "validation"):
        m = res["metrics"][split]
        assert {"rms_position_m", "max_position_m", "mean_position_m", "n"} <= set(m)
        assert m["max_position_m"] >= m["rms_position_m"] > 0
    assert res["metrics"]["train"]["n"] == 60 and res["metrics"]["validation"]["n"] == 40
    # what a tracker cannot see is reported as not identifiable (physics, not the solver):
    # the base frame and joint 1's zero are absorbed by the tracker's unknown frame
    status = {q["name"]: q for q in res["parameters"]}
    for name in ("base.x", "base.rz", "theta_offset[1]", "tool.x"):
        assert not status[name]["identifiable"] and status[name]["std"] is None


def test_html_report_is_one_file_with_embedded_images(flow):
    text = flow["rep"].read_text()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    # nothing external: every src is a data: URI, no links to other files
    srcs = re.findall(r'src="([^"]*)"', text)
    assert len(srcs) >= 5 and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert not re.search(r'(href|src)="(?!data:)', text)
    for s in srcs:
        assert base64.b64decode(s.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    for section in ("Errors before and after calibration", "What the data can identify",
                    "Parameters", "Estimated parameters against the iteration",
                    "Error distributions", "Error of every measurement"):
        assert section in text
    assert "theta_offset[2]" in text and "cannot be told apart" in text


def test_validate_command_with_training_frames_and_before(flow, capsys, tmp_path):
    out = tmp_path / "val.json"
    code, stdout, err = run(capsys, "validate", flow["cal"], "--data", flow["hold"],
                            "--result", flow["res"], "--before", "puma560", "--json", out)
    assert code == 0, err
    doc = json.loads(out.read_text())
    res = json.loads(flow["res"].read_text())
    # same protocol as calibrate --validate (training frames): identical numbers
    assert doc["overall"]["rms_position_m"] == pytest.approx(
        res["metrics"]["validation"]["rms_position_m"], rel=1e-9)
    assert doc["overall_before"]["rms_position_m"] > 20 * doc["overall"]["rms_position_m"]
    # one definition of "before" (the nominal robot, frames registered to it on the
    # training data): the same number as calibrate --validate's
    assert doc["overall_before"]["rms_position_m"] == pytest.approx(
        res["metrics"]["validation"]["before"]["rms_position_m"], rel=1e-9)
    assert doc["before_definition"] == res["metrics"]["validation"]["before_definition"]
    text = " ".join(stdout.split())
    assert "errors before -> after, one row per file" in text
    assert "before (same session) = the nominal robot, the training session's frames" in text
    assert "re-registered" not in text and "artifact" not in text     # protocols not used
    # --report: the calibration report's family, with the held-out rows measured against
    # the predicted accuracy and the protocol used
    rep = tmp_path / "val.html"
    code, _, err = run(capsys, "validate", flow["cal"], "--data", flow["hold"], "--result",
                       flow["res"], "--before", "puma560", "--report", rep)
    assert code == 0, err
    page = rep.read_text()
    assert "<h2>Errors before and after on held-out data</h2>" in page
    assert "Held-out files: measured against predicted" in page and "Predicted accuracy" in page
    assert "before (same session) = the nominal robot" in page and "ISO 9283" not in page
    assert page.count("<img") == 2 and f"{doc['overall']['rms_position_m'] * 1e3:.4f}" in page
    code, _, err = run(capsys, "validate", flow["cal"], "--data", flow["hold"], "--report",
                       flow["hold"])
    assert code == 2 and "also the input of --data" in err
    # without --result the tracker is re-registered on the file: still at the noise level
    code, stdout, _ = run(capsys, "validate", flow["cal"], "--data", flow["hold"])
    assert code == 0 and "re-registered" in stdout
    # ... and without --before no 'before' is defined, only said to be missing
    shown = " ".join(stdout.split())
    assert "before: not evaluated (--before NOMINAL gives it)" in shown
    assert "the nominal robot, the file's frame" not in shown


def test_identifiability_command(flow, capsys, tmp_path):
    out = tmp_path / "id.json"
    code, stdout, err = run(capsys, "identifiability", "puma560", "--data", flow["train"],
                            "--json", out)
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert "base.x" in doc["dependent"] and "tracker.x" in doc["dependent"]["base.x"]
    assert "theta_offset[2]" in doc["identifiable"]
    assert "identifiable" in stdout and "cannot be told apart" in stdout
    res = json.loads(flow["res"].read_text())
    assert doc["rank"] == res["identifiable_count"]


def test_moved_instrument_is_flagged_and_reregistered(flow, capsys, tmp_path):
    """A held-out file tagged like the training session but measured from another tracker
    placement (the held-out file seen from a frame moved by 0.3 m and 25 deg): the training
    frames give nonsense and kincal says so; --validation-frames register refits the
    tracker frame and marker on the file and is back at the noise level; the nominal
    robot ("before") gets the same refit."""
    from kincal.measure.registry import write_measurements
    from kincal.spatial import matrix_from_frame

    nominal = load_serial_robot("puma560")
    (h,) = read_measurements(flow["hold"], nominal)
    M = matrix_from_frame(np.array([0.3, -0.1, 0.05, math.radians(25), math.radians(3), 0.0]))
    moved_block = type(h)(h.q, h.positions @ M[:3, :3].T + M[:3, 3], h.sigma, h.name)
    moved = tmp_path / "moved.csv"
    write_measurements("position", [moved_block], moved, None, nominal)
    j = tmp_path / "r.json"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", flow["train"],
                            "--validate", moved, "--json", j)
    assert code == 0, err
    assert "probably moved between the files" in " ".join(
        stdout.split())
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", flow["train"],
                            "--validate", moved, "--json", j, "--validation-frames",
                            "register")
    assert code == 0 and "probably moved" not in stdout
    m = json.loads(j.read_text())["metrics"]
    v = m["validation"]
    assert v["rms_position_m"] < 1.5 * NOISE * math.sqrt(3)
    assert v["before"]["rms_position_m"] > 20 * v["rms_position_m"]
    assert "re-registered" in v["note"] and "frame and marker fitted" in v["note"]
    assert "before = the nominal robot under the same protocol" in v["before_definition"]
    (f,) = m["validation_files"]
    assert f["file"] == "moved.csv" and f["protocol"] == "register"
    assert f["rms_position_m"] == pytest.approx(v["rms_position_m"])


def test_calibrate_with_a_prior(flow, capsys, tmp_path):
    """The default estimate is MAP with the role tolerances; --prior entries override
    them (SI standard deviations in the JSON, a column in the table, applied in their
    unit); the prior does not change the estimated set; --prior none is least squares."""
    j = tmp_path / "map.json"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", flow["train"], "--json",
                            j, "--stages", "offsets,all",
                            "--prior", "a[*]=0.5mm,d[*]=2000um,alpha[*]=0.2deg")
    assert code == 0, err
    doc = json.loads(j.read_text())
    by = {p["name"]: p for p in doc["parameters"]}
    est = [n for n, p in by.items() if p["estimated"]]
    for n in est:
        want = {"a[": 5e-4, "d[": 2e-3, "al": math.radians(0.2),
                "th": math.radians(0.5)}.get(n[:2])       # theta_offset: the default
        assert by[n]["prior_std"] == (pytest.approx(want, rel=1e-12) if want else None), n
    assert by["d[3]"]["prior_std"] is None and not by["d[3]"]["estimated"]
    assert doc["inputs"]["prior"] == "a[*]=0.5mm,d[*]=2000um,alpha[*]=0.2deg"
    assert doc["tolerances"]["tolerances"]["a[2]"]["source"] == "--prior"
    # the prior does not change which parameters are estimated
    plain = json.loads(flow["res"].read_text())
    assert est == [p["name"] for p in plain["parameters"] if p["estimated"]]
    assert plain["inputs"]["prior"].startswith("default tolerances (length 1 mm")
    text = " ".join(stdout.split())
    robot_est = [n for n in est if not n.startswith("tracker.")]
    assert all(by[n]["prior_std"] for n in robot_est)
    assert f"MAP estimate: {len(robot_est)} estimated parameter(s) have a Gaussian prior" in text
    assert "prior (1σ)" in text and "noise scale sigma0 =" in text
    # least squares: no prior column, and the same estimated set
    j1 = tmp_path / "ls.json"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", flow["train"], "--json",
                            j1, "--prior", "none")
    assert code == 0, err
    ls = json.loads(j1.read_text())
    assert all(p["prior_std"] is None for p in ls["parameters"]) and "MAP" not in stdout
    assert ls["tolerances"]["use_prior"] is False
    # a prior far tighter than the data holds the link lengths at their nominal values
    # (1e-6 um = 1e-12 m), while the least-squares fit moves them by ~0.1 mm or more
    j2 = tmp_path / "tight.json"
    code, _, err = run(capsys, "calibrate", "puma560", "--data", flow["train"], "--json", j2,
                       "--prior", "a[*]=1e-6um")
    assert code == 0, err
    tight = {p["name"]: p for p in json.loads(j2.read_text())["parameters"]}
    moved = [abs(p["estimate"] - p["nominal"]) for p in ls["parameters"]
             if p["name"].startswith("a[") and p["estimated"]]
    held = [abs(p["estimate"] - p["nominal"]) for n, p in tight.items()
            if n.startswith("a[") and p["estimated"]]
    assert max(moved) > 1e-4 and max(held) < 1e-9


@pytest.mark.parametrize("prior,message", [
    ("a[*]=1", "'a[*]=1' needs a unit (e.g. a[*]=1mm or a[*]=1deg)"),
    ("a[*]=0.1deg", "'a[*]' matches no angle parameter"),
    ("a[*]=1furlong", "unknown unit 'furlong'"),
    ("a[*]=0mm", "must be positive"),
    ("a[*]", "is not PATTERN=SIGMA with a unit"),
    ("b[*]=1mm", "no parameter matches 'b[*]'"),
])
def test_bad_prior_one_line_exit_2_nothing_written(flow, capsys, tmp_path, prior, message):
    out = tmp_path / "res.json"
    code, _, err = run(capsys, "calibrate", "puma560", "--data", flow["train"], "--json", out,
                       "--prior", prior)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: option --prior: ")
    assert message in lines[0] and not out.exists()


BAD = {
    "wrong joint count": ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,x_mm,y_mm,z_mm\n1,2,3,4,5,1,2,3\n",
                          "line 2: no column for joint 'q6'"),
    "text in numbers": ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
                        "1,2,3,4,5,6,1,2,3\n1,2,3,4,5,6,1,two,3\n",
                        "line 4: column 8 (y_mm): 'two' is not a number"),
    "nan": ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
            "1,2,3,4,5,6,1,2,3\n1,2,NaN,4,5,6,1,2,3\n",
            "line 4: column 3 (q3_deg): 'NaN' is not a finite number"),
    "no units": ("q1,q2,q3,q4,q5,q6,x,y,z\n1,2,3,4,5,6,1,2,3\n",
                 "line 2: 9 columns have no unit: q1, q2, q3, q4, q5, q6, x, y, z"),
    "empty": ("", "line 1: the file is empty"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_measurement_file_one_line_exit_2_nothing_written(capsys, tmp_path, case):
    text, message = BAD[case]
    tag = "" if case == "empty" else "# kincal measurements: instrument=position\n"
    bad = tmp_path / "bad.csv"
    bad.write_text(tag + text)
    outs = [tmp_path / n for n in ("cal.yaml", "res.json", "rep.html")]
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", bad, "-o", outs[0],
                            "--json", outs[1], "--report", outs[2])
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad}: {message}")
    assert not any(p.exists() for p in outs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]   # no temp files


def test_console_script_exit_code(tmp_path):
    """The installed entry point (not only main()) exits 2 with one line."""
    bad = tmp_path / "bad.csv"
    bad.write_text("q1_deg,x_mm,y_mm,z_mm\n1,2,3,4\n")
    exe = Path(sys.executable).parent / "kincal"
    p = subprocess.run([str(exe), "identifiability", "puma560", "--data", str(bad)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "no column for joint 'q2'" in p.stderr


def test_compensate_command(flow, capsys, tmp_path):
    cal = load_serial_robot(flow["cal"])
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(2)
    lim = nominal.joint_limits
    q = rng.uniform(lim[:, 0] * 0.4, lim[:, 1] * 0.4, (60, 6))
    q = q[np.linalg.svd(nominal.jacobian(q), compute_uv=False)[:, -1] > 0.08][:12]
    T = nominal.fk(q)
    from kincal.spatial import matrix_to_rpy

    rpy = np.degrees(matrix_to_rpy(T[:, :3, :3]))
    rows = [",".join(f"{v:.12f}" for v in (*(T[i, :3, 3] * 1e3), *rpy[i])) for i in range(len(q))]
    targets = tmp_path / "t.csv"
    targets.write_text("x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\n" + "\n".join(rows) + "\n")
    joints, filt, js = tmp_path / "q.csv", tmp_path / "f.csv", tmp_path / "c.json"
    code, stdout, err = run(capsys, "compensate", flow["cal"], "--targets", targets, "-o",
                            joints, "--nominal", "puma560", "--filtered", filt, "--json", js,
                            "--angle-unit", "deg")
    assert code == 0, err
    head = joints.read_text().splitlines()
    assert head[1] == "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"
    qc = np.radians(np.loadtxt(joints, delimiter=",", skiprows=2, ndmin=2))
    Tt = nominal.fk(q)
    Tc = cal.fk(qc)
    # targets were written with 1e-12 mm precision; the commands hit them to ~1e-9 m
    assert np.max(np.linalg.norm(Tc[:, :3, 3] - Tt[:, :3, 3], axis=1)) < 1e-9
    F = np.loadtxt(filt, delimiter=",", skiprows=2, ndmin=2)      # in the targets' mm / deg
    assert filt.read_text().splitlines()[1].startswith("x_mm,y_mm,z_mm,rx_deg")
    np.testing.assert_allclose(F[:, :3] * 1e-3, nominal.fk(qc)[:, :3, 3], atol=1e-12)
    assert json.loads(js.read_text())["branch_changes"] == []
    # an unreachable target: exit 2, one line naming the line, nothing written
    targets.write_text(targets.read_text() + "9000,0,0,0,0,0\n")
    for p in (joints, filt):
        p.unlink()
    code, _, err = run(capsys, "compensate", flow["cal"], "--targets", targets, "-o", joints,
                       "--nominal", "puma560", "--filtered", filt)
    assert code == 2 and f"{targets}: line {len(q) + 2}: the calibrated robot cannot reach" \
        in err
    assert not joints.exists() and not filt.exists()


def test_fusion_of_two_instruments_and_patterns(capsys, tmp_path):
    """Two files (a position and a pose instrument) calibrate together; --free/--fix."""
    a, b, t = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "truth.yaml"
    assert run(capsys, "simulate", "puma560", "-o", a, "--truth", t, "--poses", "30",
               "--seed", "1")[0] == 0
    assert run(capsys, "simulate", "puma560", "-o", b, "--poses", "30", "--seed", "1",
               "--instrument", "pose", "--option", "name=probe")[0] == 0
    j = tmp_path / "r.json"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", a, "--data", b, "--json",
                            j, "--free", "role:offset,a[*],tracker.*,probe.*",
                            "--fix", "a[6]", "--loss", "huber", "--method", "gauss-newton")
    assert code == 0, err
    res = json.loads(j.read_text())
    est = {p["name"] for p in res["parameters"] if p["estimated"]}
    assert any(n.startswith("probe.") for n in est) and any(n.startswith("tracker.") for n in est)
    assert all(n.startswith(("theta_offset[", "a[", "tracker.", "probe.")) for n in est)
    assert "a[6]" not in est and res["converged"]
    # two files with the same block name: the second is renamed, not merged
    code, _, err = run(capsys, "calibrate", "puma560", "--data", a, "--data", a, "--json", j)
    assert code == 0, err
    names = {p["name"] for p in json.loads(j.read_text())["parameters"]}
    assert "tracker2.x" in names and "tracker.x" in names


#: Instruments that cannot be simulated from the command line alone, and why.
NEEDS_MORE = {"artifact": "a custom artifact needs its geometry YAML (use "
              "kincal.measure.artifacts.simulate_artifact)"}


@pytest.mark.parametrize("instrument", sorted(instruments()))
def test_simulate_works_for_every_registered_instrument(capsys, tmp_path, instrument):
    out = tmp_path / "m.csv"
    code, stdout, err = run(capsys, "simulate", "puma560", "-o", out, "--instrument",
                            instrument, "--poses", "12", "--seed", "2")
    if instrument in NEEDS_MORE:
        assert code == 2 and len(err.strip().splitlines()) == 1 and not out.exists()
        return
    assert code == 0, err
    blocks = read_measurements(out, load_serial_robot("puma560"))
    assert blocks and blocks[0].q.shape[1] == 6


def test_urdf_robot_real_data_writes_calibrated_urdf(capsys, tmp_path):
    """TIAGo motion-capture data (real): offsets + registration by least squares,
    FIGAROH's protocol; the calibrated URDF and YAML have the same forward kinematics."""
    d = DATA / "tiago_mocap"
    if not d.is_dir():
        pytest.skip("shared data not available")
    out, j = tmp_path / "tiago.yaml", tmp_path / "tiago.json"
    code, stdout, err = run(capsys, "calibrate", d / "tiago_48_schunk.urdf", "--tip-link",
                            "wrist_ft_tool_link", "--data", d / "train_2021-11-30.csv",
                            "--validate", d / "validation_2021-11-26.csv",
                            "--units", "x?=m,y?=m,z?=m", "--ignore", "?2,?3,?4",
                            "--free", "role:offset,instrument.*", "--validation-frames",
                            "training", "-o", out, "--json", j, "--prior", "none")
    assert code == 0, err
    assert "not read" in stdout and "shipped_row" in stdout
    res = json.loads(j.read_text())
    # FIGAROH's published RMS for joint offsets: 2.88 mm train / 4.23 mm validation
    assert res["metrics"]["train"]["rms_position_m"] == pytest.approx(2.88e-3, abs=0.05e-3)
    assert res["metrics"]["validation"]["rms_position_m"] == pytest.approx(4.23e-3, abs=0.1e-3)
    urdf = out.with_suffix(".urdf")
    assert urdf.is_file()
    from kincal.robots.urdf import load_urdf

    y = load_serial_robot(out)
    nominal = load_urdf(d / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")
    q = read_measurements(d / "validation_2021-11-26.csv", nominal,
                          {"x?": "m", "y?": "m", "z?": "m"}, ignore=["?2", "?3", "?4"])[0].q
    cal = load_urdf(urdf, tip_link="wrist_ft_tool_link")
    np.testing.assert_allclose(cal.fk(q), y.fk(q), atol=1e-9)


def test_demo_runs_and_writes_its_files(capsys, tmp_path):
    code, stdout, err = run(capsys, "demo", "--out-dir", tmp_path / "demo")
    assert code == 0, err
    assert "Errors before -> after" in stdout and "report:" in stdout
    for name in ("report.html", "result.json", "calibrated.yaml", "train.csv", "holdout.csv",
                 "truth.yaml"):
        assert (tmp_path / "demo" / name).is_file()
    res = json.loads((tmp_path / "demo" / "result.json").read_text())
    assert res["metrics"]["validation"]["rms_position_m"] < 5e-5


#: PUMA 560 standard DH rows (a [m], d [m], alpha [deg]); theta offsets are 0.
_PUMA_DH = [(0.0, 0.0, 90.0), (0.4318, 0.0, 0.0), (0.0203, 0.15005, -90.0),
            (0.0, 0.4318, 90.0), (0.0, 0.0, -90.0), (0.0, 0.0, 0.0)]


def _dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard DH: Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


def test_export_to_urdf_and_yaml_keeps_the_forward_kinematics(capsys, tmp_path):
    """`kincal export` writes URDF and YAML; `kincal fk` of every file gives the same T."""
    q = "0.3,-0.7,-1.1,0.4,-0.9,2.0"          # inside the joint limits
    urdf, yaml_ets, from_urdf = (tmp_path / n for n in ("puma.urdf", "puma_ets.yaml",
                                                         "from_urdf.yaml"))
    assert run(capsys, "export", "puma560", "-o", urdf)[0] == 0
    assert run(capsys, "export", "puma560", "-o", yaml_ets, "--as-ets")[0] == 0
    code, _, err = run(capsys, "export", urdf, "-o", from_urdf)
    assert code == 0, err
    Ts = []
    for spec in ("puma560", urdf, yaml_ets, from_urdf):
        j = tmp_path / "fk.json"
        code, _, err = run(capsys, "fk", spec, "--q", q, "--json", j)
        assert code == 0, err
        Ts.append(np.array(json.loads(j.read_text())["T"]))
    # truth independent of kincal's FK: the PUMA 560's published DH table (Corke &
    # Armstrong-Helouvry 1994, as in the library file), composed by hand
    T_hand = np.eye(4)
    for (a, d, alpha_deg), qi in zip(_PUMA_DH, map(float, q.split(",")), strict=True):
        T_hand = T_hand @ _dh(qi, d, a, math.radians(alpha_deg))
    for T in Ts:
        np.testing.assert_allclose(T, T_hand, atol=1e-12)
    assert "convention: ets" in yaml_ets.read_text()
    # a URDF-derived robot is `joint_units: si`: bare joint columns read as rad
    assert "joint_units: si" in from_urdf.read_text()
    assert "joint_units" not in yaml_ets.read_text()
    csv = tmp_path / "bare.csv"
    csv.write_text("# kincal measurements: instrument=position; name=t\n"
                   "q1,q2,q3,q4,q5,q6,x_mm,y_mm,z_mm\n0.1,0.2,0.3,0.4,0.5,0.6,1,2,3\n")
    block = read_measurements(csv, load_serial_robot(from_urdf))[0]
    np.testing.assert_allclose(block.q, [[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]])
    with pytest.raises(MeasurementFileError, match="have no unit"):
        read_measurements(csv, load_serial_robot("puma560"))
    # bad output names: one line, nothing written
    code, _, err = run(capsys, "export", "puma560", "-o", tmp_path / "puma.txt")
    assert code == 2 and "name it .yaml, .yml or .urdf" in err
    assert not (tmp_path / "puma.txt").exists()
    urdf_before = Path(urdf).read_bytes()
    for args in (["-o", urdf], ["-o", tmp_path / "p.yaml", "--json", urdf]):
        code, _, err = run(capsys, "export", urdf, *args)
        assert code == 2 and "also the input of ROBOT" in err, err
    assert Path(urdf).read_bytes() == urdf_before


def test_instrument_file_with_a_look_alike_column_is_an_error(capsys, tmp_path):
    """csvio follows the project rule: a column that looks like another instrument's
    measurement (az_deg in a range file) is an error unless --ignore'd."""
    path = tmp_path / "r.csv"
    assert run(capsys, "simulate", "puma560", "-o", path, "-i", "range", "--poses", "30",
               "--seed", "4", "--length-unit", "mm", "--angle-unit", "deg")[0] == 0
    lines = path.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    lines[k] += ",az_deg"
    lines[k + 1:] = [ln + ",0" for ln in lines[k + 1:]]
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "c.yaml"
    code, _, err = run(capsys, "calibrate", "puma560", "--data", path, "-o", out)
    assert code == 2 and len(err.strip().splitlines()) == 1 and not out.exists()
    assert f"{path}: line {k + 1}: column" in err and "(az_deg) looks like an instrument" in err
    code, _, err = run(capsys, "calibrate", "puma560", "--data", path, "-o", out, "--ignore",
                       "az_deg")
    assert code == 0, err
