"""The simulated experiment as a library call: the same numbers and document as
``kincal simulate --json``, reproducible from its seed."""

import json
import math

import numpy as np
from cli_helpers import run

from kincal.robots.files import load_serial_robot
from kincal.workflow.simulation import applied_noise, simulate_experiment


def test_the_library_call_gives_the_command_s_document(tmp_path, capsys):
    out, js = tmp_path / "m.csv", tmp_path / "sim.json"
    code, _, err = run(capsys, "simulate", "puma560", "-o", out, "--poses", "12", "--seed",
                       "4", "--holdout", tmp_path / "h.csv", "--holdout-poses", "5",
                       "--json", js)
    assert code == 0, err
    sim = simulate_experiment(load_serial_robot("puma560"), "position", poses=12, noise=1e-5,
                              seed=4, holdout_poses=5)
    doc = json.loads(json.dumps(sim.to_dict(output=str(out), holdout=str(tmp_path / "h.csv"))))
    cli = json.loads(js.read_text())
    assert doc == cli
    assert sim.measurements == 12 and sim.held_measurements == 5 and sim.placements == 0


def test_same_seed_same_numbers_and_perturb_limits_the_errors():
    nominal = load_serial_robot("puma560")
    a = simulate_experiment(nominal, "position", poses=6, noise=1e-5, seed=1)
    b = simulate_experiment(nominal, "position", poses=6, noise=1e-5, seed=1)
    assert np.array_equal(a.true.param_values, b.true.param_values)
    assert np.array_equal(a.blocks[0].q, b.blocks[0].q) and a.held is None
    only = simulate_experiment(nominal, "position", poses=6, noise=1e-5, seed=1,
                               perturb=["d[*]"])
    moved = [n for n, d in zip(nominal.param_names,
                               only.true.param_values - nominal.param_values, strict=True)
             if d != 0]
    assert moved and all(n.startswith("d[") for n in moved)
    noted = a.with_notes("noise 0.01 mm")
    assert "seed 1" in noted.true.meta["notes"]
    assert a.true.meta.get("notes") != noted.true.meta["notes"]          # a copy, not a change


def test_applied_noise_is_the_encoder_noise_for_artifacts():
    from kincal.measure.registry import get_instrument

    bar = get_instrument("cross-bar")
    assert applied_noise(bar, {"encoder_noise_deg": 0.01}, 1e-5) == math.radians(0.01)
    assert applied_noise(bar, {"encoder_noise_deg": -1.0}, 3e-6) == 3e-6
    assert applied_noise(get_instrument("position"), {}, 2e-5) == 2e-5
