"""The kinematics commands of the ``kincal`` CLI against the library API."""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from cli_helpers import run

from kincal.robots.dh import DHLink, from_dh
from kincal.robots.files import library_names, load_serial_robot, write_robot_yaml

Q = [0.1, -0.4, 0.7, 1.2, -0.5, 2.0]
Q_TEXT = ",".join(str(v) for v in Q)


def run_cli(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """``kincal ARGS`` in-process with a wide terminal (tables unwrapped)."""
    monkeypatch.setenv("COLUMNS", "200")
    return run(capsys, *args)


@pytest.fixture
def prismatic_file(tmp_path):
    """A DH robot R P R with a tool frame, written as YAML."""
    links = [DHLink(a=0.1, d=0.2, alpha=np.pi / 2), DHLink(a=0.0, d=0.3, joint="prismatic"),
             DHLink(a=0.05, d=0.0, alpha=-np.pi / 2, theta_offset=0.3)]
    robot = from_dh(links, name="rpr", tool=(0, 0, 0.1, 0, 0.2, 0))
    path = tmp_path / "rpr.yaml"
    write_robot_yaml(robot, path)
    return path, robot


def test_robots_lists_the_library(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "robots")
    assert code == 0, err
    for name in library_names():
        assert name in out
    assert "RRRRRR" in out and "standard_dh" in out


def test_show_lists_joints_and_parameters(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "show", "puma560")
    assert code == 0, err
    robot = load_serial_robot("puma560")
    for name in robot.param_names + robot.joint_names:
        assert name in out
    rows = {ln.split("│")[1].strip(): ln for ln in out.splitlines() if ln.count("│") >= 4}
    assert "431.8000" in rows["a[2]"] and "│ mm " in rows["a[2]"]        # value and unit agree
    assert "90.0000" in rows["alpha[1]"] and "│ deg " in rows["alpha[1]"]
    assert "-160.0 deg" in out
    assert "d1 = 0" in out and "0.672 m" in out        # the notes: why RTB's PUMA differs
    code, out, err = run_cli(monkeypatch, capsys, "show", "puma560", "--si")
    rows = {ln.split("│")[1].strip(): ln for ln in out.splitlines() if ln.count("│") >= 4}
    assert "0.4318000" in rows["a[2]"] and "│ m " in rows["a[2]"]


def test_show_json_to_stdout_is_pure_json(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "show", "puma560", "--json", "-")
    assert code == 0, err
    data = json.loads(out)                      # no table before the JSON
    robot = load_serial_robot("puma560")
    assert data["name"] == "puma560"
    assert [p["name"] for p in data["parameters"]] == list(robot.param_names)
    np.testing.assert_array_equal([p["value"] for p in data["parameters"]], robot.param_values)


def test_fk_json_equals_api(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "fk", "puma560", "--q", Q_TEXT, "--json", "-")
    assert code == 0, err
    data = json.loads(out)                      # stdout holds only the JSON
    T = np.array(data["T"])
    assert T.shape == (4, 4)
    np.testing.assert_array_equal(T, load_serial_robot("puma560").fk(Q))


def test_fk_table_output(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "fk", "puma560", "--q", Q_TEXT)
    assert code == 0, err
    T = load_serial_robot("puma560").fk(Q)
    assert f"{T[0, 3] * 1e3:.4f}" in out and "position [mm]" in out
    code, out, err = run_cli(monkeypatch, capsys, "fk", "puma560", "--q", Q_TEXT, "--si")
    assert f"{T[0, 3]:.7f}" in out and "position [m]" in out


def test_fk_deg_converts_revolute_joints_only(monkeypatch, capsys, prismatic_file):
    path, robot = prismatic_file
    code, out, err = run_cli(monkeypatch, capsys, "fk", str(path), "--q", "30,0.25,-45",
                             "--deg", "--json", "-")
    assert code == 0, err
    want = robot.fk([np.deg2rad(30), 0.25, np.deg2rad(-45)])
    np.testing.assert_allclose(np.array(json.loads(out)["T"]), want, atol=1e-15)
    # without --deg the same numbers are radians and metres
    code, out, _ = run_cli(monkeypatch, capsys, "fk", str(path), "--q", "30,0.25,-45",
                           "--json", "-")
    np.testing.assert_allclose(np.array(json.loads(out)["T"]), robot.fk([30, 0.25, -45]),
                               atol=1e-15)


def test_jacobian_tool_frame_json(monkeypatch, capsys, prismatic_file):
    code, out, err = run_cli(monkeypatch, capsys, "jacobian", "puma560", "--q", Q_TEXT,
                             "--frame", "tool", "--json", "-")
    assert code == 0, err
    data = json.loads(out)
    J = np.array(data["J"])
    assert J.shape == (6, 6) and data["frame"] == "tool"
    assert data["columns"] == ["q1", "q2", "q3", "q4", "q5", "q6"]
    np.testing.assert_array_equal(J, load_serial_robot("puma560").jacobian(Q, frame="tool"))
    path, robot = prismatic_file
    code, out, err = run_cli(monkeypatch, capsys, "jacobian", str(path), "--q", "0.3,0.1,0.2",
                             "--json", "-")
    assert code == 0, err
    J = np.array(json.loads(out)["J"])
    assert J.shape == (6, 3)
    np.testing.assert_array_equal(J, robot.jacobian([0.3, 0.1, 0.2]))
    np.testing.assert_array_equal(J[3:, 1], 0.0)            # prismatic: no rotation


@pytest.mark.parametrize("args, message", [
    (["fk", "puma560", "--q", "1,2,3"], "--q: expected 6 comma-separated values, got 3"),
    (["jacobian", "puma560", "--q", "1,2,3,4,5,6,7"], "expected 6 comma-separated values"),
    (["fk", "puma560", "--q", "1,2,x,4,5,6"], "'x' is not a number"),
    (["fk", "puma560", "--q", "1,2,nan,4,5,6"], "finite"),
    (["jacobian", "puma560", "--q", Q_TEXT, "--frame", "world"], "frame 'world'"),
    (["show", "puma561"], "unknown robot 'puma561'"),
])
def test_user_errors_are_one_line_exit_2(monkeypatch, capsys, args, message):
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err


def test_real_processes():
    """The console entry point in separate processes: JSON on stdout, errors exit 2."""
    cmd = [sys.executable, "-c", "from kincal.cli import main; main()"]
    jobs = [cmd + ["fk", "puma560", "--q", Q_TEXT, "--json", "-"],
            cmd + ["fk", "puma560", "--q", "1,2,3"]]
    with ThreadPoolExecutor(2) as pool:
        ok, bad = pool.map(lambda a: subprocess.run(a, capture_output=True, text=True,
                                                    timeout=120), jobs)
    assert ok.returncode == 0, ok.stderr
    np.testing.assert_array_equal(np.array(json.loads(ok.stdout)["T"]),
                                  load_serial_robot("puma560").fk(Q))
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip() == ("error: option --q: expected 6 comma-separated values, "
                                  "got 3")
