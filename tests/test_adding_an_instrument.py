"""The page docs/adding-an-instrument.md, run as written: its Python blocks in order, in
one namespace, in a scratch folder; the calibration with the new instrument must find
the simulated truth within its standard errors."""

from __future__ import annotations

import re
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
    ns: dict[str, object] = {"__name__": "adding_an_instrument"}
    try:
        for code in page_code():
            exec(compile(code, str(PAGE), "exec"), ns)
        yield ns
    finally:
        registry._REGISTRY.pop("laser-distance", None)


def test_the_page_has_its_three_steps() -> None:
    assert len(page_code()) == 3


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
