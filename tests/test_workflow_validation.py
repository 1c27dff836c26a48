"""Validation on held-out files as a library call: the true robot fits its own simulated
measurements to the noise, the nominal robot does not, and the document says so."""

import json

from kincal.robots.files import load_serial_robot
from kincal.workflow.simulation import simulate_experiment
from kincal.workflow.validation import validate_on_files

NOISE = 1e-5


def test_the_true_robot_validates_at_the_noise_and_the_nominal_does_not():
    nominal = load_serial_robot("puma560")
    sim = simulate_experiment(nominal, "position", poses=40, noise=NOISE, seed=2)
    val = validate_on_files(sim.true, sim.blocks, before=nominal)
    assert val.robot == "puma560" and val.compared_before and val.accuracy is None
    doc = json.loads(json.dumps(val.to_dict(), default=float))
    assert doc["overall"]["n"] == 40
    assert doc["overall"]["rms_position_m"] < 3 * NOISE < doc["overall_before"]["rms_position_m"]
    assert set(doc["files"]) == {b.source_label for b in sim.blocks}
    assert "predicted" not in doc and "iso9283" not in doc and doc["before_definition"]
    alone = validate_on_files(sim.true, sim.blocks)
    assert "overall_before" not in alone.to_dict()
