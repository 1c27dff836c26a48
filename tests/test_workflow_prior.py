"""The workflow's Python API takes a typed prior; the command line parses text into it.

Truth: the same calibration given the prior as command-line text (parsed by
:func:`parse_prior_text`) and as the typed mapping in SI gives the same estimate to
1e-12; the literals ``"tolerances"`` / ``"none"`` mean what ``--prior`` without a value
and ``--prior none`` mean.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.tolerances import TolSpec
from kincal.measure.registry import simulate_measurements
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot
from kincal.workflow.flow import check_flow_options, run_flow, tolerances_of
from kincal.workflow.options import parse_prior_text, prior_given, prior_spec


@pytest.fixture(scope="module")
def sim():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    true = perturb_robot(nominal, rng, length_std=5e-4, angle_std=math.radians(0.05),
                         offset_std=math.radians(0.1))
    train, _ = simulate_measurements("position", true, rng, 40, 1e-5, {"name": "tracker"})
    return nominal, train


def test_literals_and_mappings_become_tolerance_entries() -> None:
    assert prior_spec(None) == prior_spec("tolerances") == TolSpec()
    assert prior_spec("none") == TolSpec(use_prior=False)
    spec = prior_spec({"length": 5e-4, "d[3]": None})
    assert [(e.target, e.value) for e in spec.entries] == [("length", 5e-4), ("d[3]", None)]
    assert not prior_given(None) and prior_given("none") and prior_given({"length": 1e-3})
    assert parse_prior_text(None) is None
    assert parse_prior_text("scale=3").scale == 3.0


@pytest.mark.parametrize(("prior", "fragment"), [
    ("length=0.5mm", "the Python API takes 'tolerances', 'none', a mapping"),
    ({"length": -1e-3}, "the standard deviation must be positive"),
    ({"length": math.nan}, "the standard deviation must be positive"),
])
def test_text_and_bad_values_are_one_line_errors(prior, fragment) -> None:
    with pytest.raises(KincalError, match=fragment):
        prior_spec(prior)


def test_staged_selection_refuses_a_typed_prior_as_it_refuses_the_option() -> None:
    with pytest.raises(KincalError, match="--prior choose the one-stage solver"):
        check_flow_options(procedure="staged-selection", prior={"length": 1e-3})
    check_flow_options(procedure="staged-selection", prior="tolerances")       # the default: fine


def test_typed_prior_gives_the_estimate_of_its_text(sim) -> None:
    nominal, train = sim
    text = run_flow(nominal, train, prior=parse_prior_text("length=0.5mm,d[3]=none"),
                    max_iter=50).result
    typed = run_flow(nominal, train, prior={"length": 0.5e-3, "d[3]": None},
                     max_iter=50).result
    assert text.estimated == typed.estimated
    np.testing.assert_allclose(typed.theta, text.theta, rtol=1e-12, atol=1e-15)
    from kincal.measure.base import stack

    tol = tolerances_of(nominal, stack(nominal, train)[0], {"length": 0.5e-3, "d[3]": None})
    assert "d[3]" not in tol.sigma and tol.sigma["a[2]"] == 0.5e-3


def test_none_literal_is_least_squares(sim) -> None:
    nominal, train = sim
    flow = run_flow(nominal, train, prior="none", max_iter=50)
    assert not flow.result.prior
    assert run_flow(nominal, train, prior="tolerances", max_iter=50).result.prior
