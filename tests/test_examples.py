"""Every setup file under examples/setups runs, and gives the README's numbers.

Each is one real-data calibration of the README (../shared/data), run as a user runs
it: ``kincal calibrate --config examples/setups/NAME.yaml`` (outputs redirected to a
temporary folder).  The numbers are the README's, from the data the fit never saw.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import run

from kincal.workflow.config import load_setup

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "setups"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

#: What each example must reproduce: JSON metric path -> (lower, upper) [SI].
EXPECTED = {
    # README: TIAGo, all four markers, MAP + hysteresis + compliance: 1.269 / 2.808 mm
    "tiago_mocap": {("train", "rms_position_m"): (1.1e-3, 1.4e-3),
                    ("validation", "rms_position_m"): (2.6e-3, 3.07e-3)},
    # README / FIGAROH: joint offsets (14 parameters): 2.876 / 4.229 mm (FIGAROH 2.88 / 4.23)
    "tiago_offsets": {("train", "rms_position_m"): (2.7e-3, 3.0e-3),
                      ("validation", "rms_position_m"): (4.0e-3, 4.5e-3)},
    # README: Motoman, 5-fold cross-validated RMS 0.073 mm (nominal 0.343 mm)
    "motoman_right": {("cross_validation", "rms_position_m"): (0.06e-3, 0.085e-3)},
    # README: Panda, left placement: ball spread 0.239 mm, socket distance error +0.012 mm
    "panda_two_socket": {("validation", "rms_coincidence_m"): (0.15e-3, 0.3e-3),
                         ("validation", "max_distance_m"): (0.0, 0.1e-3)},
    # IPA UR10 read as recorded (';', ',' decimals, ROS names, euler:XYZ, per-axis sigma as
    # weights with the unmodelled floor added): train series B 0.443 mm, held-out series C
    # 1.241 mm (nominal 1.937 mm)
    "ipa_ur10": {("train", "rms_position_m"): (0.40e-3, 0.50e-3),
                 ("validation", "rms_position_m"): (1.15e-3, 1.35e-3)},
    # MUKCa Pandas (folders as recorded): held-out placements' ball spread and socket distance
    "mukca_panda_2": {("validation", "rms_coincidence_m"): (0.65e-3, 0.85e-3),
                      ("validation", "rms_distance_m"): (0.20e-3, 0.35e-3)},
    "mukca_panda_3": {("validation", "rms_coincidence_m"): (0.20e-3, 0.28e-3),
                      ("validation", "rms_distance_m"): (0.0, 0.15e-3)},
    "mukca_panda_4": {("validation", "rms_coincidence_m"): (0.24e-3, 0.32e-3),
                      ("validation", "rms_distance_m"): (0.10e-3, 0.30e-3)},
    "mukca_panda_7": {("validation", "rms_coincidence_m"): (0.27e-3, 0.36e-3),
                      ("validation", "rms_distance_m"): (0.05e-3, 0.20e-3)},
    # ROS-I positioner, observation YAML as recorded: 5-fold CV 0.417 mm (nominal 0.463)
    "rosi_positioner": {("cross_validation", "rms_position_m"): (0.36e-3, 0.46e-3)},
}


def test_every_example_has_expectations():
    assert sorted(p.stem for p in EXAMPLES.glob("*.yaml")) == sorted(EXPECTED)


#: Held-out files whose own registration fits them far better than the training frames
#: (the frames add more error than everything else): kincal must say so.  The IPA UR10's
#: series C (the data set says one tracker set-up): 0.62 against 1.24 mm; the TIAGo's
#: validation day with the full model (FIGAROH's protocol keeps the mocap frame and the
#: markers): 1.84 against 2.87 mm.  The other setups' held-out files agree with their
#: training frames.
WARNINGS = {"ipa_ur10": "measurements_random_poses.csv: with the training frames the held-out "
                        "RMS is",
            "tiago_mocap": "validation_2021-11-26.csv: with the training frames the held-out "
                           "RMS is"}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_example_setup_reproduces_the_readme(name, tmp_path, capsys):
    if not DATA.is_dir():
        pytest.skip(f"real data not found at {DATA}")
    setup = EXAMPLES / f"{name}.yaml"
    load_setup(setup)                                      # valid as it is
    out = {k: tmp_path / f"{name}.{ext}" for k, ext in (("-o", "yaml"), ("--json", "json"),
                                                          ("--report", "html"),
                                                          ("--urdf", "urdf"))}
    code, stdout, err = run(capsys, "calibrate", "--config", setup,
                            *[x for k, v in out.items() for x in (k, v)])
    assert code == 0, err
    doc = json.loads(out["--json"].read_text())
    print(f"\n{name}: " + ", ".join(
        f"{a} {b} = {doc['metrics'][a][b] * 1e3:.4f} mm" for a, b in EXPECTED[name]))
    for (section, key), (lo, hi) in EXPECTED[name].items():
        value = doc["metrics"][section][key]
        assert lo <= value <= hi, f"{name}: {section}.{key} = {value * 1e3:.4f} mm"
    assert out["-o"].is_file() and out["--report"].is_file()
    said = " ".join(doc["warnings"])
    if name in WARNINGS:
        assert WARNINGS[name] in said and "probably moved between the files" in said, said
    else:
        assert "probably moved between the files" not in said, said
