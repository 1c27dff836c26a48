"""ISO 9283: test cube, pose accuracy AP, repeatability RP, distance accuracy AD.

Checked against values computed by hand, a simulated robot whose truth is known, and the
repeatability sets of the Motoman / Leica data.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.identify.iso9283 import (
    CYCLE,
    cube_positions,
    distance_figures,
    group_positions,
    pose_figures,
)
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot, write_robot_yaml
from kincal.spatial import rotx

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motoman_leica"


def test_pose_figures_by_hand():
    """Attained (1,0,0), (0,1,0), (0,0,1) mm about a commanded origin: the mean is
    (1,1,1)/3, AP = sqrt(3)/3; every l_i = sqrt(6)/3, S_l = 0, RP = sqrt(6)/3 mm."""
    f = pose_figures("P1", np.eye(3) * 1e-3, np.zeros(3))
    assert f.AP == pytest.approx(math.sqrt(3) / 3 * 1e-3, rel=1e-12)
    assert f.RP == pytest.approx(math.sqrt(6) / 3 * 1e-3, rel=1e-12)
    # l = 0, 0, 3 (points 0, 0, 3 along x about mean 1): l = 1, 1, 2; mean 4/3,
    # S = sqrt(((1/3)^2 * 2 + (2/3)^2) / 2) = sqrt(1/3); RP = 4/3 + 3 sqrt(1/3)
    p = np.array([[0.0, 0, 0], [0, 0, 0], [3, 0, 0]])
    f = pose_figures("P2", p)
    assert math.isnan(f.AP)
    assert f.RP == pytest.approx(4 / 3 + 3 * math.sqrt(1 / 3), rel=1e-12)


def test_orientation_figures_by_hand():
    """Attained rotations of +1 and -1 mrad about x and a commanded 0.5 mrad about x:
    AP_a = 0 - 0.5 mrad... relative rotations +0.5 and -1.5 mrad: mean -0.5 mrad,
    S = sqrt(2) mrad, RP_a = 3 sqrt(2) mrad."""
    A = np.tile(np.eye(4), (2, 1, 1))
    A[0, :3, :3], A[1, :3, :3] = rotx(1e-3), rotx(-1e-3)
    C = np.eye(4)
    C[:3, :3] = rotx(0.5e-3)
    f = pose_figures("P1", A, C)
    assert f.AP_abc[0] == pytest.approx(-0.5e-3, rel=1e-9)
    assert f.RP_abc[0] == pytest.approx(3 * math.sqrt(2) * 1e-3, rel=1e-9)
    assert f.AP == pytest.approx(0.0, abs=1e-15)


def test_distance_figures_by_hand():
    a = np.array([[0.0, 0, 0], [0, 0, 0]])
    b = np.array([[1.0, 0, 0], [1.2, 0, 0]])
    d = distance_figures(a, b, [0, 0, 0], [1.05, 0, 0])
    assert d["D_mean_m"] == pytest.approx(1.1)
    assert d["AD_m"] == pytest.approx(0.05)
    assert d["RD_m"] == pytest.approx(3 * math.sqrt(0.02))


def test_cube_positions_lie_on_the_diagonal_plane_at_10_percent():
    P = cube_positions([1.0, 2.0, 3.0], 0.4)
    h = 0.2
    assert np.allclose(P["P1"], [1, 2, 3])
    c = np.array([1.0, 2.0, 3.0])
    corners = {"P2": [-h, -h, -h], "P3": [-h, h, -h], "P4": [h, h, h], "P5": [h, -h, h]}
    diag = math.sqrt((2 * h) ** 2 * 3)          # a diagonal of the plane (= cube diagonal)
    for name, corner in corners.items():
        assert np.linalg.norm(P[name] - (c + corner)) == pytest.approx(0.1 * diag)
    n = np.cross(np.array([0, 2 * h, 0]), np.array([2 * h, 0, 2 * h]))   # plane normal
    for p in P.values():
        assert abs(np.dot(p - (c + corners["P2"]), n)) < 1e-15


def test_positions_are_grouped_by_joint_values_in_cycle_order():
    rng = np.random.default_rng(0)
    base = rng.uniform(-1, 1, (5, 6))
    rows = np.array([base[k] + rng.normal(0, 1e-5, 6) for _ in range(3) for k in range(5)])
    assert group_positions(rows) == list(CYCLE) * 3


def _measurement_file(path: Path, robot, q: np.ndarray, y: np.ndarray, sigma: float) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        f.write("# kincal measurements: instrument=position; name=tracker\n")
        w.writerow([f"{j}_rad" for j in robot.joint_names] + ["x_mm", "y_mm", "z_mm",
                                                               "sigma_mm"])
        for qi, yi in zip(q, y, strict=True):
            w.writerow([repr(float(v)) for v in qi] + [repr(float(v) * 1e3) for v in yi]
                       + [repr(sigma * 1e3)])


def test_plan_and_validate_on_a_simulated_robot(tmp_path, capsys):
    """Plan the cube, simulate a tracker (10 um) on a robot with known errors, and check
    the figures: RP equals the hand formula on the simulated points; the true model's AP
    is at the noise level, the nominal model's AP is its known offset."""
    plan = tmp_path / "iso.csv"
    code, out, err = run(capsys, "plan", "kr6", "--iso9283", "--cycles", "10", "-o", plan,
                         "--cube-size", "300mm", "--json", tmp_path / "plan.json")
    assert code == 0, err
    doc = json.loads((tmp_path / "plan.json").read_text())
    rows = [r for r in csv.reader(open(plan)) if r and not r[0].startswith("#")]
    q = np.radians(np.array([[float(v) for v in r] for r in rows[1:]])) \
        if "deg" in rows[0][0] else np.array([[float(v) for v in r] for r in rows[1:]])
    assert len(q) == 50
    nominal = load_serial_robot("kr6")
    assert np.allclose(nominal.fk(q[:5])[:, :3, 3], [doc["positions_m"][n] for n in CYCLE],
                       atol=1e-9)
    truth = perturb_robot(nominal, np.random.default_rng(1))
    write_robot_yaml(truth, tmp_path / "truth.yaml")
    rng = np.random.default_rng(2)
    y = truth.fk(q)[:, :3, 3] + rng.normal(0, 1e-5, (len(q), 3))
    data = tmp_path / "cycles.csv"
    _measurement_file(data, nominal, q, y, 1e-5)
    code, out, err = run(capsys, "validate", tmp_path / "truth.yaml", "--data", data,
                         "--before", "kr6", "--iso9283", "--json", tmp_path / "v.json")
    assert code == 0, err
    assert "AP before [mm]" in out and "RP [mm]" in out
    iso = json.loads((tmp_path / "v.json").read_text())["iso9283"]["cycles.csv"]
    labels = group_positions(q)
    for f_after, f_before in zip(iso["after"], iso["before"], strict=True):
        rows_k = [i for i, n in enumerate(labels) if n == f_after["position"]]
        p = y[rows_k]
        l = np.linalg.norm(p - p.mean(0), axis=1)
        assert f_after["RP_m"] == pytest.approx(l.mean() + 3 * l.std(ddof=1), rel=1e-12)
        assert f_after["AP_m"] < 3 * 1e-5 * math.sqrt(3 / 10) + 2e-6     # noise / sqrt(n)
        assert f_before["AP_m"] > 10 * f_after["AP_m"]
    assert "distance_P2_P4_after" in iso
    # --report: the ISO 9283 section, per position, before and after, and the distances
    code, out, err = run(capsys, "validate", tmp_path / "truth.yaml", "--data", data,
                         "--before", "kr6", "--iso9283", "--report", tmp_path / "iso.html")
    assert code == 0, err
    page = (tmp_path / "iso.html").read_text()
    assert "<h2>ISO 9283 acceptance figures</h2>" in page and "AP before [mm]" in page
    for f in iso["after"]:
        assert f"<td class='l'>{f['position']}</td><td>10</td>" in page
        assert f"{f['RP_m'] * 1e3:.4f}" in page
    assert "distance P2-P4 (after): AD" in page and "nan" not in page
    # --si: the same figures in m, in the tables of validate and plan
    code, out, err = run(capsys, "validate", tmp_path / "truth.yaml", "--data", data,
                         "--before", "kr6", "--iso9283", "--si")
    assert code == 0, err
    assert "AP before [m]" in out and "RP [m]" in out and "[mm]" not in out
    rp = iso["after"][0]["RP_m"]
    assert f"{rp:.7f}" in out
    assert re.search(r"AD -?\d\.\d{7} m, RD \d\.\d{7} m", " ".join(out.split())), out
    code, out, err = run(capsys, "plan", "kr6", "--iso9283", "--cycles", "2", "-o",
                         tmp_path / "iso2.csv", "--cube-size", "300mm", "--si")
    assert code == 0, err
    assert "x [m]" in out and "edge 0.3000 m" in out and "mm" not in out


@pytest.mark.parametrize("name", ["right_arm_repeatability_table1.csv",
                                  "right_arm_repeatability_wall1.csv"])
def test_rp_on_the_motoman_repeatability_sets(name, tmp_path, capsys):
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"real data not found: {path}")
    code, out, err = run(capsys, "validate", "motoman_right", "--data", path, "--iso9283",
                         "--json", tmp_path / "v.json")
    assert code == 0, err
    iso = json.loads((tmp_path / "v.json").read_text())["iso9283"][name]["after"]
    rows = list(csv.DictReader(open(path)))
    y = np.array([[float(r[c]) for c in ("x_m", "y_m", "z_m")] for r in rows])
    assert len(iso) == 1 and iso[0]["cycles"] == len(y)
    l = np.linalg.norm(y - y.mean(0), axis=1)
    assert iso[0]["RP_m"] == pytest.approx(l.mean() + 3 * l.std(ddof=1), rel=1e-12)
    print(f"\n{name}: ISO 9283 RP {iso[0]['RP_m'] * 1e3:.4f} mm over {len(y)} cycles")
    assert 0.005e-3 < iso[0]["RP_m"] < 0.2e-3
