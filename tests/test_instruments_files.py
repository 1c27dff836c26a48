"""CSV formats of the instruments: write then read gives the same model; bad files give
one line naming the file and the line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.measure.instruments import HandCameraMeasurement
from kincal.measure.registry import (
    get_instrument,
    read_measurements,
    simulate_measurements,
    write_measurements,
)
from kincal.robots.files import load_serial_robot

ROBOT = load_serial_robot("puma560")

CASES = {
    "range": ("range", {"stations": 3}),
    "range-incremental": ("range", {"incremental": True, "marker": "tool"}),
    "bearing": ("bearing", {}),
    "camera": ("camera", {}),
    "camera-hand": ("camera", {"mount": "hand"}),
    "plane": ("plane", {}),
    "plane-known": ("plane", {"known": True, "planes": 3}),
    "fixture": ("fixture", {}),
}


def simulate(key: str) -> tuple[str, list]:
    inst, opts = CASES[key]
    noise = {"m": 1e-5, "rad": 5e-6, "px": 0.1}[get_instrument(inst).noise_unit]
    blocks, _ = simulate_measurements(inst, ROBOT, np.random.default_rng(1), 8, noise, opts)
    return inst, blocks


ATTRS = ("q", "obs", "sigma", "marker", "station_labels", "mode", "run", "intrinsics",
         "plane_labels", "s", "K")


def same(a: object, b: object) -> None:
    assert type(a) is type(b)
    assert a.name == b.name
    assert a.parameters().names == b.parameters().names
    assert np.allclose(a.parameters().values, b.parameters().values, rtol=1e-12, atol=1e-15)
    for attr in ATTRS:
        if hasattr(a, attr):
            x, y = getattr(a, attr), getattr(b, attr)
            if isinstance(x, np.ndarray):
                assert np.allclose(x, y, rtol=1e-12, atol=1e-15), attr
            elif isinstance(x, dict):
                assert x.keys() == y.keys()
                assert np.allclose(list(x.values()), list(y.values()), rtol=1e-12), attr
            else:
                assert list(x) == list(y) if not isinstance(x, str) else x == y, attr
    if hasattr(a, "plane_defs"):
        for k, (n, d, known) in a.plane_defs.items():
            n2, d2, known2 = b.plane_defs[k]
            assert np.allclose(n, n2, atol=1e-14) and np.isclose(d, d2, rtol=1e-12)
            assert known == known2
    x = a.parameters().values + 1e-3
    assert np.allclose(a.evaluate(ROBOT, x, False)[0], b.evaluate(ROBOT, x, False)[0],
                       rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("units", [{"length": "mm", "angle": "deg"},
                                   {"length": "m", "angle": "rad"}])
@pytest.mark.parametrize("key", list(CASES))
def test_round_trip(key: str, units: dict, tmp_path: Path) -> None:
    inst, blocks = simulate(key)
    path = tmp_path / f"{key}.csv"
    write_measurements(inst, blocks, path, units, robot=ROBOT)
    first = path.read_text().splitlines()[0]
    assert first.startswith(f"# kincal measurements: instrument={inst}; name=")
    header = next(ln for ln in path.read_text().splitlines() if not ln.startswith("#"))
    assert f"q1_{units['angle']}" in header
    back = read_measurements(path, ROBOT)
    assert len(back) == 1
    same(blocks[0], back[0])


def test_hand_camera_file_has_target_points(tmp_path: Path) -> None:
    inst, blocks = simulate("camera-hand")
    path = tmp_path / "hand.csv"
    write_measurements(inst, blocks, path, {"length": "mm", "angle": "deg"}, robot=ROBOT)
    text = path.read_text()
    assert "mount=hand" in text.splitlines()[0]
    assert "target_x_mm,target_y_mm,target_z_mm,u_px,v_px,fx_px,fy_px,cx_px,cy_px,sigma_px" \
        in text
    assert isinstance(read_measurements(path, ROBOT)[0], HandCameraMeasurement)


def test_constants_on_line_one_and_name_override(tmp_path: Path) -> None:
    path = tmp_path / "adm.csv"
    path.write_text("# kincal measurements: instrument=range; name=adm; sigma_um=5\n"
                    "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,station,range_mm\n"
                    "0,10,20,30,40,50,s1,1500.25\n"
                    "5,15,25,35,45,55,s2,1700.5\n")
    b = read_measurements(path, ROBOT)[0]
    assert b.name == "adm"
    assert np.allclose(b.sigma, 5e-6) and np.allclose(b.obs[:, 0], [1.50025, 1.7005])
    assert b.stations == ("s1", "s2") and b.marker == "own"
    assert read_measurements(path, ROBOT, name="lasers")[0].parameters().names[0] == \
        "lasers.s1.x"


GOOD = {
    "range": "# kincal measurements: instrument=range; name=r\n"
             "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,station,range_mm,sigma_mm\n"
             "0,10,20,30,40,50,s1,1500.25,0.01\n"
             "5,15,25,35,45,55,s2,1700.5,0.01\n",
    "camera": "# kincal measurements: instrument=camera; name=c\n"
              "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,station,u_px,v_px,fx_px,fy_px,"
              "cx_px,cy_px,sigma_px\n"
              "0,10,20,30,40,50,c1,100,200,2000,2000,1024,768,0.1\n"
              "5,15,25,35,45,55,c1,110,210,2000,2000,1024,768,0.1\n",
    "plane": "# kincal measurements: instrument=plane; name=p\n"
             "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,plane,mode,n_az_deg,n_el_deg,d_mm,"
             "sigma_mm\n"
             "0,10,20,30,40,50,top,known,0,90,-200,0.005\n"
             "5,15,25,35,45,55,top,known,0,90,-200,0.005\n",
    "fixture": "# kincal measurements: instrument=fixture; name=f; sigma_mm=0.02\n"
               "# fixture points in the world frame\n"
               "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
               "0,10,20,30,40,50,500,100,200\n"
               "5,15,25,35,45,55,500,100,200\n",
}

BAD = [
    # (base file, old text, new text, expected line, message fragment)
    ("range", "1700.5,0.01", "17oo.5,0.01", 4, "'17oo.5' is not a number"),
    ("range", "1700.5,0.01", "1700.5", 4, "values, but the header has"),
    ("range", "range_mm,sigma_mm", "range,sigma_mm", 2, "has no unit"),
    ("range", "range_mm,sigma_mm", "range_deg,sigma_mm", 2, "expected a length"),
    ("range", ",sigma_mm\n", ",extra_mm\n", 2, "missing column 'sigma'"),
    ("range", "1500.25,0.01", "1500.25,-0.01", 3, "standard deviation must be positive"),
    ("range", "s2,1700.5", "s 2,1700.5", 4, "station label 's 2'"),
    ("range", "station,", "mode,", 2, "missing column 'station'"),
    ("range", "name=r", "name=r; marker=flange", 1, "marker='flange'"),
    ("range", "instrument=range", "instrument=range; sigma_mm=0.1", 1, "repeats column"),
    ("fixture", "sigma_mm=0.02", "sigma_mm=x", 1, "'x' is not a number"),
    ("fixture", "sigma_mm=0.02", "sigma_deg=0.02", 1, "unit deg is not a length"),
    ("fixture", "sigma_mm=0.02", "sigma=0.02", 3, "missing column 'sigma'"),
    ("fixture", "instrument=fixture", "instrument=plane", 3, "(x_mm) looks like a measurement"),
    ("fixture", "x_mm,y_mm", "x_mm,q7_mm", 3, "looks like a joint column"),
    ("camera", "55,c1,110,210,2000", "55,c1,110,210,2100", 4, "camera intrinsics differs "
     "from line 3"),
    ("camera", "fx_px,fy_px", "fx_mm,fy_px", 2, "expected a pixel"),
    ("camera", "50,c1,100,200,2000,2000", "50,c1,100,200,0,2000", 3, "must be positive"),
    ("plane", "55,top,known,0,90,-200", "55,top,known,0,90,-210", 4, "differs from line 3"),
    ("plane", "55,top,known", "55,top,maybe", 4, "'maybe' is not one of known, unknown"),
    ("plane", "55,top,known", "55,top,unknown", 4, "plane mode 'unknown' differs"),
]


@pytest.mark.parametrize("base, old, new, line, fragment", BAD)
def test_bad_file_gives_one_line_with_file_and_line(base: str, old: str, new: str, line: int,
                                                    fragment: str, tmp_path: Path) -> None:
    good = tmp_path / "good.csv"
    good.write_text(GOOD[base])
    read_measurements(good, ROBOT)                         # the unmodified file is fine
    assert old in GOOD[base]
    path = tmp_path / "bad.csv"
    path.write_text(GOOD[base].replace(old, new, 1))
    with pytest.raises(MeasurementFileError) as info:
        read_measurements(path, ROBOT)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: line {line}:"), msg
    assert fragment in msg, msg


def test_write_refuses_several_blocks(tmp_path: Path) -> None:
    inst, blocks = simulate("range")
    with pytest.raises(MeasurementFileError, match="one measurement block"):
        write_measurements(inst, blocks * 2, tmp_path / "x.csv", robot=ROBOT)
    assert not (tmp_path / "x.csv").exists()
