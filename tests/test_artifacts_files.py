"""Artifact CSV files, geometry YAML and plain per-socket files: units at the border,
labels kept, one-line errors naming the file and line.

Truth is written by hand (values in deg / mm compared with SI numbers) or comes from
a different unit of the writer; the Panda files are cross-checked with ``numpy.loadtxt``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.measure.artifacts import (
    ArtifactGeometry,
    Probe,
    merge_blocks,
    read_artifact,
    read_geometry,
    read_socket_files,
    write_geometry,
)
from kincal.measure.registry import (
    read_measurements,
    simulate_measurements,
    write_measurements,
)
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="module")
def puma():
    return load_serial_robot("puma560")


@pytest.mark.parametrize("instrument,options", [
    ("cross-bar", {"placements": 3, "probe": "length", "encoder_noise_deg": 0.002}),
    ("ball-bar", {"placements": 3, "probe": "vector", "length_std_mm": 0.01}),
    ("two-socket", {"placements": 1, "visits": 3, "sockets": "parameters",
                    "seat_noise_mm": 0.02}),
])
def test_written_files_read_back_identically_in_other_units(tmp_path, puma, instrument,
                                                            options):
    rng = np.random.default_rng(0)
    (b,), _ = simulate_measurements(instrument, perturb_robot(puma, rng), rng, 0, 1e-5,
                                    options)
    path = tmp_path / "m.csv"
    write_measurements(instrument, [b], path, {"length": "mm", "angle": "deg"}, puma)
    text = path.read_text().splitlines()
    assert text[0].startswith(f"# kincal measurements: instrument={instrument}; ")
    assert text[2].startswith("placement,point,q1_deg,")
    (c,) = read_measurements(path, puma)
    np.testing.assert_allclose(c.q, b.q, rtol=1e-13, atol=1e-13)
    assert c.placement_labels == b.placement_labels and c.socket_labels == b.socket_labels
    assert c.geometry == b.geometry and c.sockets == b.sockets and c.name == b.name
    assert c.probe.mode == b.probe.mode and c.probe.estimate == b.probe.estimate
    np.testing.assert_allclose(c.probe.value, b.probe.value, rtol=1e-13, atol=1e-15)
    assert c.joint_std == pytest.approx(b.joint_std, rel=1e-12)
    assert c.point_std == pytest.approx(b.point_std, rel=1e-12, abs=1e-18)


def test_hand_written_file_in_degrees_one_placement_per_file(tmp_path, puma):
    text = ("# kincal measurements: instrument=ball-bar; length_mm=150; probe=length; "
            "probe_length_mm=120; joint_std_deg=0.002\n"
            "# a comment\n"
            "socket,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,operator\n"
            "A,10,20,30,40,50,60,ann\n"
            "B,-10,-20,-30,-40,-50,-60,bob\n"
            "B,1,2,3,4,5,6,bob\n")
    p1 = tmp_path / "monday.csv"
    p1.write_text(text)
    (b,) = read_artifact(p1, puma)
    np.testing.assert_allclose(b.q[0], np.radians([10, 20, 30, 40, 50, 60]), rtol=1e-15)
    assert b.placements == ("monday",) and b.socket_labels == ("A", "B", "B")
    assert b.geometry.length == pytest.approx(0.150) and b.probe.value == (0.12,)
    assert b.joint_std == pytest.approx(math.radians(0.002)) and b.point_std == 0.0
    assert b.sites.count.tolist() == [1, 2]                      # B seated twice
    p2 = tmp_path / "tuesday.csv"
    p2.write_text(text.replace("A,10", "A,11"))
    (c,) = read_artifact(p2, puma)
    both = merge_blocks([b, c], name="bar")
    assert both.placements == ("monday", "tuesday") and both.N == 6 and both.name == "bar"
    assert len(both.lengths(puma).value) == 2


def test_custom_geometry_yaml(tmp_path, puma):
    g = ArtifactGeometry("custom", ("P", "Q", "R"),
                         (ArtifactGeometry.ball_bar(0.2, 1e-5, ("P", "Q")).distances[0],),
                         (), {"P": (0, 0, 0), "Q": (0.2, 0, 0), "R": (0, 0.1, 0)})
    y = tmp_path / "plate.yaml"
    write_geometry(g, y)
    assert read_geometry(y) == g
    y.write_text("artifact: cross-bar\nlength: 300\n")
    with pytest.raises(MeasurementFileError, match="length unit"):
        read_geometry(y)
    y.write_text("artifact: cross-bar\nunits: {length: mm, angle: deg}\nlength: 300\n"
                 "angle_std: 0.01\n")
    cross = read_geometry(y)
    assert cross.length == pytest.approx(0.3) and cross.perpendiculars[0].std == \
        pytest.approx(math.radians(0.01))
    rng = np.random.default_rng(1)
    from kincal.measure.artifacts import simulate_artifact

    b, _ = simulate_artifact(puma, g, 2, rng, Probe.length(0.1), point_std=1e-5,
                             name="plate")
    path = tmp_path / "plate.csv"
    write_measurements("artifact", [b], path, {"length": "mm", "angle": "deg"}, puma)
    assert (tmp_path / "plate.geometry.yaml").is_file()
    (c,) = read_measurements(path, puma)
    assert c.geometry == g and c.socket_labels == b.socket_labels


@pytest.mark.parametrize("body,match", [
    ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n1,2,3,4,5,6\n", "no 'point' column"),
    ("point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nA,1,2,3,4,5,6\nE,1,2,3,4,5,6\n",
     "line 4: socket 'E'"),
    ("point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nA,1,2,3,4,x,6\n", "line 3"),
    ("point,q1,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nA,1,2,3,4,5,6\n", "has no unit"),
])
def test_bad_files_are_one_line_errors(tmp_path, puma, body, match):
    p = tmp_path / "bad.csv"
    p.write_text("# kincal measurements: instrument=cross-bar; length_mm=300\n" + body)
    with pytest.raises(MeasurementFileError, match=match) as err:
        read_measurements(p, puma)
    assert "bad.csv" in str(err.value) and "\n" not in str(err.value)


def test_bad_tags(tmp_path, puma):
    body = "point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nA,1,2,3,4,5,6\n"
    for tags, match in (("", "missing tag length"), ("; length_deg=3", "length unit"),
                        ("; length_mm=300; probe=stick", "probe='stick'"),
                        ("; length_mm=300; probe=length", "probe_length")):
        p = tmp_path / "t.csv"
        p.write_text(f"# kincal measurements: instrument=cross-bar{tags}\n" + body)
        with pytest.raises(MeasurementFileError, match=match):
            read_measurements(p, puma)


def test_plain_socket_files(tmp_path):
    d = tmp_path / "place"
    d.mkdir()
    np.savetxt(d / "s0.csv", np.radians([[10.0, 20.0], [30.0, 40.0]]), delimiter=",")
    np.savetxt(d / "s1.csv", np.radians([[50.0, 60.0]]), delimiter=",")
    s = read_socket_files(d)
    assert s.socket == ("s0", "s0", "s1") and s.placement == ("place",) * 3
    np.testing.assert_allclose(s.q, np.radians([[10, 20], [30, 40], [50, 60]]), rtol=1e-15)
    np.savetxt(d / "deg.csv", [[1.0, 2.0]], delimiter=",")
    s2 = read_socket_files([d / "deg.csv"], angle_unit="deg", placement="p")
    np.testing.assert_allclose(s2.q, np.radians([[1.0, 2.0]]))
    (d / "s2.csv").write_text("1,2,3\n")
    with pytest.raises(MeasurementFileError, match="3 joint values per row"):
        read_socket_files(d)


def test_panda_socket_files_match_loadtxt():
    folder = DATA / "panda_two_socket" / "front"
    if not folder.is_dir():
        pytest.skip(f"Panda two-socket data not found at {folder}")
    s = read_socket_files(folder, angle_unit="rad")
    ref = np.vstack([np.loadtxt(folder / f"hole_{k}.csv", delimiter=",") for k in (0, 1)])
    np.testing.assert_array_equal(s.q, ref)
    assert s.socket.count("hole_0") == 31 and s.socket.count("hole_1") == 31
    assert set(s.placement) == {"front"}
