"""The staged-selection procedure (angles, then lengths) through the command line
(issue 4): simulate a cross-bar experiment, calibrate it with ``--procedure
staged-selection --condition-growth``, and check the
calibrated robot against the truth on held-out placements.

Truth is independent of the solver: ``kincal simulate --truth`` writes the true robot,
and the noise level of a bar length is derived from the encoder noise alone, by central
finite differences of the *true* robot's forward kinematics (first-order propagation:
``var L = s_q^2 (|u^T J_a|^2 + |u^T J_b|^2)``, ``u`` the unit vector between the two
probe tips, ``J`` the tip's Jacobian with respect to the joints).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import invoke, run

from kincal.measure.registry import read_measurements
from kincal.robots.files import load_serial_robot

PLACEMENTS = 12
BAR_MM, PROBE_MM = 300.0, 100.0
ENCODER_DEG = 0.001



@pytest.fixture(scope="module")
def staged(tmp_path_factory):
    """simulate (training + held-out placements) -> calibrate --procedure staged-selection,
    once."""
    d = tmp_path_factory.mktemp("staged")
    f = {k: d / v for k, v in (("cb", "cb.csv"), ("hold", "hold.csv"), ("truth", "truth.yaml"),
                               ("sim", "sim.json"), ("cal", "cal.yaml"), ("json", "r.json"),
                               ("html", "r.html"))}
    sim = ["simulate", "puma560", "--instrument", "cross-bar", "--placements", PLACEMENTS,
           "--bar-length", f"{BAR_MM}mm", "--probe-length", f"{PROBE_MM}mm", "--encoder-noise",
           f"{ENCODER_DEG}deg", "--seed", 3, "-o", f["cb"], "--truth", f["truth"],
           "--holdout", f["hold"], "--json", f["sim"]]
    cal = ["calibrate", "puma560", "--data", f["cb"], "--procedure", "staged-selection",
           "--condition-growth", "1.0", "-o", f["cal"], "--json", f["json"], "--report",
           f["html"]]
    for key, args in (("sim", sim), ("cal", cal)):
        assert invoke(*args) == 0, f"{key} failed"
    return f


def _length_sigma(robot, block, sigma_q: float, tip: np.ndarray) -> float:
    """RMS standard deviation of the block's bar lengths from encoder noise alone [m]."""
    q = block.q

    def tips(qq: np.ndarray) -> np.ndarray:
        T = robot.fk(qq)
        return T[:, :3, 3] + T[:, :3, :3] @ tip

    eps = 1e-7
    J = np.stack([(tips(q + eps * e) - tips(q - eps * e)) / (2 * eps)
                  for e in np.eye(q.shape[1])], axis=2)          # (N, 3, n)
    P = tips(q)
    pl, so = np.array(block.placement_labels), np.array(block.socket_labels)
    var = []
    for p in dict.fromkeys(block.placement_labels):
        for a, b in (("A", "C"), ("B", "D")):
            ia = int(np.flatnonzero((pl == p) & (so == a))[0])
            ib = int(np.flatnonzero((pl == p) & (so == b))[0])
            u = (P[ib] - P[ia]) / np.linalg.norm(P[ib] - P[ia])
            var.append(sigma_q**2 * (np.sum((u @ J[ia]) ** 2) + np.sum((u @ J[ib]) ** 2)))
    return float(np.sqrt(np.mean(var)))


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def test_simulate_flags_reach_the_instrument(staged):
    sim = json.loads(staged["sim"].read_text())
    assert sim["placements"] == PLACEMENTS and sim["measurements"] == 4 * PLACEMENTS
    assert sim["encoder_noise_rad"] == pytest.approx(math.radians(ENCODER_DEG), rel=1e-12)
    assert sim["instrument_options"]["bar_length_mm"] == BAR_MM
    assert sim["instrument_options"]["probe_length_mm"] == PROBE_MM
    header = staged["cb"].read_text().splitlines()[0]
    assert "length_m=0.3" in header and "probe_length_m=0.1" in header


def test_staged_selection_record_and_comparison_in_the_json(staged, capsys):
    res = json.loads(staged["json"].read_text())
    info = res["staged_selection"]
    kept, dropped = info["kept"], info["discarded"]
    print(f"condition-number selection kept {len(kept)} of {PLACEMENTS} placements")
    assert len(kept) + len(dropped) == PLACEMENTS and len(info["selection"]) == PLACEMENTS
    # 18 identifiable parameters, 3 constraints per placement: at least 6 are needed
    assert 6 <= len(kept) <= PLACEMENTS
    assert info["condition_growth"] == 1.0 and info["converged"] is True
    for step in info["selection"]:                     # the rule, step by step
        if step["previous"] is not None and step["condition"] is not None:
            assert step["kept"] == (step["condition"] <= step["previous"])
    # training errors come from the kept placements only: 2 lengths and 1 angle each
    train = res["metrics"]["train"]
    assert train["n"] == 2 * len(kept)
    # the one-stage comparison: same data, same parameters, agreeing within their errors
    comp = info["comparison"]
    assert {"same_parameters", "staged_selection", "one_stage", "automatic"} <= set(comp)
    assert comp["one_stage"]["estimated"] == comp["staged_selection"]["estimated"] == \
        res["estimated_count"]
    assert comp["same_parameters"]["max_sigmas"] < 2.0
    assert res["method"] == "staged-selection" and res["inputs"]["procedure"] == "staged-selection"


def test_calibrated_bar_lengths_on_held_out_placements_are_at_the_noise_level(staged):
    nominal, truth, cal = (load_serial_robot(x)
                           for x in ("puma560", staged["truth"], staged["cal"]))
    held = read_measurements(staged["hold"], nominal)[0]
    train = read_measurements(staged["cb"], nominal)[0]
    assert held.q.shape == train.q.shape and not np.allclose(held.q, train.q)  # new placements
    sigma_L = _length_sigma(truth, held, math.radians(ENCODER_DEG),
                            np.array([0.0, 0.0, PROBE_MM * 1e-3]))
    assert 5e-6 < sigma_L < 5e-5                         # ~0.015 mm for 0.001 deg
    L_true, L_cal, L_nom = (held.lengths(r) for r in (truth, cal, nominal))
    assert np.allclose(L_true.target, BAR_MM * 1e-3)
    # the truth itself: the readings' noise only
    assert rms(L_true.error) == pytest.approx(sigma_L, rel=0.5)
    # calibrated model vs the truth on the same readings (noise cancels): the estimation
    # error of 18 parameters from the kept placements, within 2.5 sigma_L
    assert rms(L_cal.value - L_true.value) < 2.5 * sigma_L
    # against the known bar length: noise + estimation error, within 3 sigma_L
    assert rms(L_cal.error) < 3 * sigma_L
    # the nominal model is far off (the injected errors)
    assert rms(L_nom.error) > 40 * sigma_L


def test_report_has_the_staged_selection_section_and_figures(staged):
    text = staged["html"].read_text()
    assert "The staged-selection procedure" in text or "The staged-selection procedure" in text
    assert "Data selection by the condition number" in text and "discarded" in text
    assert "Comparison with one-stage Levenberg-Marquardt" in text
    assert text.rstrip().endswith("</html>")
    outputs = json.loads(staged["json"].read_text())["outputs"]
    for key in ("lengths_nominal", "lengths_calibrated", "lengths_calibrated_zoom"):
        png = Path(outputs[key])
        assert png.parent == staged["html"].parent and png.name.startswith("r_lengths")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert text.count("data:image/png;base64,") >= 3 + 3   # report plots + the figures


@pytest.mark.parametrize("args, fragment", [
    (["--condition-growth", "1.5"], "need --procedure staged-selection"),
    (["--procedure", "staged-selection", "--method", "gauss-newton"],
     "the staged-selection procedure has its own"),
    (["--procedure", "staged-selection", "--condition-growth", "0.5"], "must be >= 1"),
    (["--procedure", "nope"], "is not lm or staged-selection"),
])
def test_bad_staged_selection_options_are_one_line_and_write_nothing(staged, capsys, tmp_path,
                                                                     args, fragment):
    out = tmp_path / "c.yaml"
    code, _, err = run(capsys, "calibrate", "puma560", "--data", staged["cb"], "-o", out,
                       *args)
    assert code == 2 and len(err.strip().splitlines()) == 1 and fragment in err, err
    assert not out.exists()


def test_artifact_flags_need_an_artifact_instrument(capsys, tmp_path):
    out = tmp_path / "m.csv"
    code, _, err = run(capsys, "simulate", "puma560", "-o", out, "--bar-length", "300mm")
    assert code == 2 and "--bar-length" in err and "position" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    # two-socket: --bar-length is the socket distance
    code, _, err = run(capsys, "simulate", "puma560", "-o", out, "--instrument", "two-socket",
                       "--bar-length", "6cm", "--placements", "2", "--option", "visits=2",
                       "--seed", "1", "--json", tmp_path / "s.json")
    assert code == 0, err
    opts = json.loads((tmp_path / "s.json").read_text())["instrument_options"]
    assert opts["socket_distance_mm"] == 60.0 and opts["placements"] == 2
    # the same option twice
    code, _, err = run(capsys, "simulate", "puma560", "-o", tmp_path / "x.csv", "-i",
                       "ball-bar", "--placements", "3", "--option", "placements=4")
    assert code == 2 and "given twice" in err and not (tmp_path / "x.csv").exists()
