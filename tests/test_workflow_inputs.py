"""The run's inputs as the report and the result JSON show them."""


from kincal.workflow.inputs import calibration_inputs


def test_defaults_are_spelled_out():
    got = calibration_inputs(robot="puma560", data=["a.csv", "b.csv"])
    assert got["data"] == "a.csv, b.csv" and got["validation"] == "-"
    assert got["free"] == "automatic (identifiable set)" and got["fixed"] == "-"
    assert got["prior"].startswith("default tolerances (length ")
    assert got["joint model"] == "geometric only" and got["model selection"] == "none"
    assert "cycles" not in got


def test_staged_selection_adds_its_stages_and_options():
    got = calibration_inputs(robot="r", data=["x.csv"], procedure="staged-selection",
                             staged=True, condition_growth=1.5, tolerance=2e-7, folds=5)
    assert got["procedure"] == "staged-selection" and got["stages"] == "angles, lengths"
    assert got["method"].startswith("staged selection (two stages")
    assert got["condition growth"] == "1.5" and got["cycles"] == "until converged"
    assert got["tolerance"] == "0.0002 mm"
    assert got["model selection"].startswith("--select auto, 5-fold")
