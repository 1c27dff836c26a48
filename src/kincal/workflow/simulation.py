"""A simulated calibration experiment: what ``kincal simulate`` does, as a library call.

A true robot is the nominal one plus Gaussian errors by role
(:func:`kincal.measure.simulate.perturb_robot`: lengths ``length_std`` [m], angles
``angle_std`` [rad], joint offsets ``offset_std`` [rad], the base and tool frames
``(length_std, angle_std)``); a registered instrument measures it at ``poses``
configurations with noise ``noise`` (standard deviation per coordinate, in the
instrument's unit: m, rad or px), optionally again on ``holdout_poses`` held-out
configurations (same placement where the instrument can reuse it).  One random generator
seeded with ``seed`` draws, in this order, the errors, the measurements and the held-out
measurements, so the same call gives the same numbers.

:func:`simulate_experiment` returns a :class:`SimulatedExperiment`; its
:meth:`~SimulatedExperiment.to_dict` is the JSON document of ``kincal simulate --json``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from kincal.measure.base import HasPlacements, MeasurementModel
from kincal.measure.registry import InstrumentPlugin, get_instrument, simulate_measurements
from kincal.measure.simulate import perturb_robot
from kincal.robots.chain import Robot

__all__ = ["SimulatedExperiment", "simulate_experiment", "applied_noise"]


def applied_noise(instrument: InstrumentPlugin, options: Mapping[str, Any], noise: float
                  ) -> float:
    """The noise the simulation really applies, in SI: for artifact instruments (an
    ``encoder_noise_deg`` option) the encoder noise per joint ``radians(encoder_noise_deg)``
    [rad] when it is >= 0, else ``noise``; for the others ``noise`` itself."""
    if "encoder_noise_deg" in instrument.options:
        enc = options.get("encoder_noise_deg", instrument.options["encoder_noise_deg"][0])
        return math.radians(enc) if enc >= 0 else noise
    return noise


@dataclasses.dataclass(frozen=True)
class SimulatedExperiment:
    """The true robot, the measurements of it and the instrument's true parameters.

    Attributes:
        nominal: the robot the errors were added to.
        true: the true robot (its ``meta["notes"]`` say how it was simulated, see
            :meth:`with_notes`).
        instrument: the registered instrument that measured it.
        blocks: the training measurements.
        held: the held-out measurements, or None.
        instrument_truth: the instrument's true parameters (frame, markers ...) [m, rad].
        options: the instrument options used.
        noise: the main noise (standard deviation) in the instrument's unit.
        seed: the random generator's seed.
        poses: the number of configurations asked for.
    """

    nominal: Robot
    true: Robot
    instrument: InstrumentPlugin
    blocks: list[MeasurementModel]
    held: list[MeasurementModel] | None
    instrument_truth: dict[str, float]
    options: dict[str, Any]
    noise: float
    seed: int
    poses: int

    @property
    def measurements(self) -> int:
        """Rows of the training measurements."""
        return sum(int(b.q.shape[0]) for b in self.blocks)

    @property
    def held_measurements(self) -> int:
        """Rows of the held-out measurements (0 without them)."""
        return sum(int(b.q.shape[0]) for b in self.held or [])

    @property
    def placements(self) -> int:
        """Artifact placements of the training measurements (0 for other instruments)."""
        return sum(len(b.placements) for b in self.blocks if isinstance(b, HasPlacements))

    def with_notes(self, noise_text: str) -> SimulatedExperiment:
        """The same experiment, the true robot's notes saying how it was simulated
        (``noise_text``: the noise as people read it, e.g. ``"noise 0.01 mm"``)."""
        note = (f"Simulated by `kincal simulate`: {self.nominal.name} + errors (seed "
                f"{self.seed}), measured by {self.instrument.name} with {noise_text}; "
                "instrument truth: "
                + ", ".join(f"{k}={v:.9g}" for k, v in self.instrument_truth.items()))
        true = dataclasses.replace(self.true, meta={**dict(self.true.meta), "notes": note})
        return dataclasses.replace(self, true=true)

    def to_dict(self, output: str | None = None, holdout: str | None = None,
                truth_file: str | None = None) -> dict[str, Any]:
        """The JSON document of ``kincal simulate --json`` (the files as given)."""
        inst = self.instrument
        doc: dict[str, Any] = {
            "robot": self.nominal.name, "instrument": inst.name, "poses": self.poses,
            "measurements": self.measurements, "noise": self.noise,
            "noise_unit": inst.noise_unit, "seed": self.seed, "output": output,
            "holdout": holdout, "truth_file": truth_file,
            "instrument_options": self.options, "instrument_truth": self.instrument_truth,
            "true_parameters": self.true.params(),
            "nominal_parameters": self.nominal.params()}
        if "encoder_noise_deg" in inst.options:
            doc["encoder_noise_rad"] = applied_noise(inst, self.options, self.noise)
            doc["placements"] = self.placements
        return doc


def simulate_experiment(nominal: Robot, instrument: str | InstrumentPlugin, *, poses: int,
                        noise: float, options: Mapping[str, Any] | None = None,
                        seed: int = 0, length_std: float = 5e-4,
                        angle_std: float = math.radians(0.05),
                        offset_std: float = math.radians(0.1),
                        perturb: Sequence[str] | None = None,
                        holdout_poses: int | None = None) -> SimulatedExperiment:
    """Simulate a calibration experiment (module docstring).

    Args:
        nominal: the nominal robot.
        instrument: a registered instrument or its name.
        poses: measured configurations (artifacts: see the instrument's options).
        noise: measurement noise (standard deviation) in the instrument's unit.
        options: instrument options (typed like their defaults).
        seed: seed of the one random generator.
        length_std, angle_std, offset_std: standard deviations of the injected length
            [m], angle [rad] and joint offset [rad] errors.
        perturb: only perturb the parameters these names or ``*`` patterns match.
        holdout_poses: also simulate this many held-out configurations.
    """
    from kincal.identify.names import match_names

    inst = get_instrument(instrument) if isinstance(instrument, str) else instrument
    opts = dict(options or {})
    rng = np.random.default_rng(seed)
    names = None
    if perturb:
        names = [nominal.param_names[i] for i in match_names(nominal.param_names, perturb)]
    true = perturb_robot(nominal, rng, length_std=length_std, angle_std=angle_std,
                         offset_std=offset_std, base_std=(length_std, angle_std),
                         tool_std=(length_std, angle_std), names=names)
    blocks, inst_truth = simulate_measurements(inst, true, rng, poses, noise, opts)
    held = None
    if holdout_poses is not None:
        hopts = dict(opts)
        if not inst.same_placement and "name" in inst.options:
            hopts["name"] = f"{opts.get('name', inst.options['name'][0])}_holdout"
        held, _ = simulate_measurements(inst, true, rng, holdout_poses, noise, hopts,
                                        truth=inst_truth)
    return SimulatedExperiment(nominal, true, inst, blocks, held, inst_truth, opts, noise,
                               seed, poses)
