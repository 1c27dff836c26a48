"""The page docs/adding-an-instrument.md, run as written: its first three Python blocks
are one module, written to ``laser_distance.py`` in a scratch folder and imported (which
registers the instrument); the last block calibrates with it and must find the simulated
truth within its standard errors."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from kincal.measure import registry

PAGE = Path(__file__).resolve().parents[1] / "docs" / "adding-an-instrument.md"


def page_code() -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", PAGE.read_text(), flags=re.S | re.M)


@pytest.fixture
def page(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    *module, calibration = page_code()
    (tmp_path / "laser_distance.py").write_text("\n\n".join(module))
    ns: dict[str, object] = {"__name__": "adding_an_instrument"}
    try:
        exec(compile(calibration, str(PAGE), "exec"), ns)
        yield ns
    finally:
        registry._REGISTRY.pop("laser-distance", None)
        sys.modules.pop("laser_distance", None)


def test_the_page_has_its_four_steps() -> None:
    assert len(page_code()) == 4


def test_the_instrument_is_one_module(page) -> None:
    """Model, file columns, simulator and registration all come from laser_distance.py."""
    module = sys.modules["laser_distance"]
    plugin = registry.get_instrument("laser-distance")
    for piece in (plugin.simulate, plugin.write, plugin.read):
        assert piece.__module__ == "laser_distance"
    assert module.LaserDistance.__module__ == "laser_distance"


def test_the_new_instrument_calibrates_a_simulated_robot(page) -> None:
    res, truth, block = page["result"], page["truth"], page["block"]
    assert res.converged, res.message
    robot_estimated = [n for n in res.estimated if n in page["nominal"].param_names]
    assert len(robot_estimated) >= 10 and set(robot_estimated) == set(page["free"])
    errors = np.array([(res.params[n] - truth[n]) / res.std[res.names.index(n)]
                       for n in res.estimated])
    assert np.all(np.abs(errors) < 4.5), dict(zip(res.estimated, errors.round(1), strict=True))
    # the start was really wrong, and the estimate is far better than it
    moved = max(abs(truth[n] - page["nominal"].params()[n]) for n in page["free"])
    assert moved > 1e-4 and page["worst"] < 4.5
    # the block came from the file, and the registry treats it like any instrument
    assert block.provenance.path == "laser.csv" and len(block.provenance.table) == 300
    assert "laser.csv" in repr(block)
    assert registry.detect_instrument("laser.csv") == "laser-distance"
    np.testing.assert_allclose(block.measurement_sigma(), 1e-5, rtol=1e-9)


@pytest.mark.parametrize("name", ["position", "pose", "range", "bearing", "camera", "plane",
                                  "fixture"])
def test_kincal_instruments_follow_the_same_layout(name) -> None:
    """Each of kincal's own instruments is one module of measure/instruments/, listed in
    INSTRUMENT_MODULES: its simulator, writer and reader are defined there."""
    module = f"kincal.measure.instruments.{name}"
    assert module in registry.INSTRUMENT_MODULES
    plugin = registry.get_instrument(name)
    assert {plugin.simulate.__module__, plugin.write.__module__, plugin.read.__module__} \
        == {module}
