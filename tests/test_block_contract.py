"""The declared measurement-block contract: provenance travels with every wrapper and
copy by construction, capabilities are protocols, and the instrument registry raises on
kincal's own broken modules while reporting broken third-party plug-ins."""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest

from kincal.errors import MeasurementFileError
from kincal.measure import registry
from kincal.measure.base import (
    BlockWrapper,
    HasPlacements,
    HasProbe,
    MeasurementModel,
    PredictsObservations,
    PredictsPoints,
    Provenance,
)
from kincal.measure.joints.terms import with_joint_model
from kincal.measure.registry import (
    read_measurements,
    simulate_measurements,
    write_measurements,
)
from kincal.robots.files import load_serial_robot

PUMA = load_serial_robot("puma560")


@pytest.fixture(scope="module")
def position_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("contract") / "tracker.csv"
    blocks, _ = simulate_measurements("position", PUMA, np.random.default_rng(4), 12, 1e-5)
    write_measurements("position", blocks, path, {"length": "mm", "angle": "deg"}, PUMA)
    return path


@pytest.fixture(scope="module")
def cross_bar_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("contract") / "cross.csv"
    blocks, _ = simulate_measurements("cross-bar", PUMA, np.random.default_rng(5), 16, 1e-4)
    write_measurements("cross-bar", blocks, path, {"length": "mm", "angle": "deg"}, PUMA)
    return path


def test_a_read_block_knows_its_file_and_table(position_file) -> None:
    (b,) = read_measurements(position_file, PUMA)
    assert b.provenance == Provenance(str(position_file), b.provenance.table)
    assert b.provenance.table.path == str(position_file) and len(b.provenance.table) == 12
    assert b.source_label == str(position_file)
    assert "tracker.csv" in repr(b) and "tracker.csv" in b._repr_html_()
    np.testing.assert_array_equal(b.measurement_sigma(), b.sigma)


def test_a_simulated_block_has_no_provenance() -> None:
    (b,), _ = simulate_measurements("range", PUMA, np.random.default_rng(1), 8, 1e-5)
    assert b.provenance is None and b.source_label == b.name
    assert "from" not in repr(b)


def test_wrappers_share_the_inner_provenance(position_file) -> None:
    (b,) = read_measurements(position_file, PUMA)
    (w,) = with_joint_model([b], PUMA, ["hysteresis"])
    assert isinstance(w, BlockWrapper) and w.provenance is b.provenance
    np.testing.assert_array_equal(w.measurement_sigma(), b.sigma)
    # set on the wrapper, seen by the block it wraps (one record, not two copies)
    w.provenance = Provenance("elsewhere.csv")
    assert b.provenance.path == "elsewhere.csv"
    # a copy at other joint readings keeps it too
    assert w.with_q(w.q + 0.01).provenance.path == "elsewhere.csv"


def test_artifact_copies_keep_their_provenance(cross_bar_file) -> None:
    (b,) = read_measurements(cross_bar_file, PUMA)
    assert b.provenance is not None and b.provenance.path == str(cross_bar_file)
    assert isinstance(b, HasPlacements) and isinstance(b, HasProbe)
    assert isinstance(b, PredictsPoints) and not isinstance(b, PredictsObservations)
    kept = b.subset_placements(b.placements[:2])
    assert kept.provenance is b.provenance and kept.placements == b.placements[:2]
    assert b.with_q(b.q).provenance is b.provenance


def test_position_and_pose_declare_their_capabilities(position_file) -> None:
    (b,) = read_measurements(position_file, PUMA)
    assert isinstance(b, PredictsObservations) and not isinstance(b, HasPlacements)
    assert not isinstance(b, HasProbe)
    (p,), _ = simulate_measurements("pose", PUMA, np.random.default_rng(2), 5, 1e-5)
    np.testing.assert_array_equal(p.measurement_sigma(), p.sigma_position)


def test_every_registered_instrument_is_a_plugin() -> None:
    for name, inst in registry.instruments().items():
        assert inst.name == name and inst.noise_unit in ("m", "rad", "px")
        assert callable(inst.simulate) and callable(inst.read) and callable(inst.write)
    assert not registry.get_instrument("plane").same_placement
    assert registry.get_instrument("range").same_placement


@pytest.fixture
def fresh_registry(monkeypatch):
    known = dict(registry.instruments())          # kincal's own, registered on import
    monkeypatch.setattr(registry, "_REGISTRY", known)
    monkeypatch.setattr(registry, "_loaded", False)
    monkeypatch.setattr(registry, "LOAD_ERRORS", {})
    return registry


def test_an_error_in_kincal_own_instrument_module_raises(fresh_registry, monkeypatch) -> None:
    monkeypatch.setattr(fresh_registry, "INSTRUMENT_MODULES",
                        ("kincal.measure.no_such_instrument_module",))
    with pytest.raises(ModuleNotFoundError, match="no_such_instrument_module"):
        fresh_registry.instruments()


def test_a_broken_third_party_plugin_is_reported(fresh_registry, monkeypatch) -> None:
    ep = importlib.metadata.EntryPoint("broken", "no_such_plugin_module",
                                       registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(fresh_registry, "entry_points",
                        lambda group: [ep] if group == registry.ENTRY_POINT_GROUP else [])
    known = fresh_registry.instruments()
    assert "position" in known
    assert list(fresh_registry.LOAD_ERRORS) == ["broken (no_such_plugin_module)"]
    with pytest.raises(MeasurementFileError, match="plug-in broken .* failed to load"):
        fresh_registry.get_instrument("laser")


def test_the_block_contract_is_abstract() -> None:
    with pytest.raises(TypeError):
        MeasurementModel()  # type: ignore[abstract]
