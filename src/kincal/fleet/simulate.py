"""Simulated fleets: many robots of one model, several sessions each, some drifted, some broken.

:func:`simulate_fleet` writes ``ROOT/<serial>/<date>/tracker.csv`` for every robot and
session, a fleet manifest ``ROOT/fleet.yaml`` listing them, and ``ROOT/truth.json`` with
what was injected:

* every robot is the nominal model plus its own errors
  (:func:`~kincal.measure.simulate.perturb_robot`: lengths ``length_error`` [m], twists
  ``angle_error`` [rad], encoder zeros ``offset_error`` [rad]); each session places the
  tracker anew and measures ``poses`` random configurations with Gaussian noise
  ``noise`` [m] per coordinate;
* ``drifted`` robots change one identifiable parameter between their last two sessions
  by ``drift_sigma`` times its predicted combined standard error
  ``sigma_c = sqrt(2) * sigma_1``, where ``sigma_1`` is the standard error of the first
  session's calibration at the stated noise (:func:`predicted_std`), drawn among the
  parameters whose drift stays within three times their manufacturing error;
* ``broken`` robots get an unreadable last-session file (a row with a non-numeric
  value).

Robot ``k`` draws from its own stream ``default_rng([seed, k])``, so a robot is the same
whatever the fleet size.  SI units inside; files in mm and deg.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from kincal.errors import KincalError
from kincal.io import atomic_write_text

__all__ = ["SimulatedFleet", "simulate_fleet", "predicted_std", "serial_name"]


@dataclasses.dataclass
class SimulatedFleet:
    """What :func:`simulate_fleet` wrote.

    Attributes:
        root: the fleet's folder.
        manifest: ``root / "fleet.yaml"``.
        truth: ``root / "truth.json"``.
        robots: per robot ``{"serial", "dates", "drift": {parameter, change, unit,
            sigma_combined, sigmas} | None, "broken": {date, file, line} | None}``.
    """

    root: Path
    manifest: Path
    truth: Path
    robots: list[dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: the paths as text and each robot's record without its true
        parameters (those are in ``truth.json``)."""
        return {"root": str(self.root), "manifest": str(self.manifest),
                "truth": str(self.truth),
                "robots": [{k: v for k, v in r.items() if k != "true_parameters"}
                           for r in self.robots]}


def serial_name(k: int) -> str:
    """The serial number of the ``k``-th simulated robot (``R-00001``)."""
    return f"R-{k + 1:05d}"


def predicted_std(robot: Any, blocks: list[Any], truth: dict[str, float]
                  ) -> dict[str, float]:
    """Predicted standard error [m, rad] of every parameter kincal estimates from a design:
    the calibration of ``blocks`` started at the true values (``truth``), its covariance
    ``sigma0^2 (J^T J)^-1`` divided by ``sigma0^2`` (the stated noise, not the sample's)."""
    from kincal.identify.solver import calibrate

    known = {n: v for n, v in truth.items() if n not in robot.param_names}
    res = calibrate(robot, blocks, initial=known or None)
    s0 = res.sigma0 if res.sigma0 > 0 else 1.0
    return {n: float(res.std[res.names.index(n)] / s0) for n in res.estimated}


def _corrupt(path: Path, rng: np.random.Generator) -> int:
    """Replace one value of a data row with text; returns its line number (1-based)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    data = [i for i, s in enumerate(lines) if s and not s.startswith("#") and s[0] not in "qx"]
    i = data[int(rng.integers(1, len(data)))]
    cells = lines[i].split(",")
    cells[int(rng.integers(0, len(cells)))] = "n/a"
    lines[i] = ",".join(cells)
    atomic_write_text(path, "\n".join(lines) + "\n")
    return i + 1


def simulate_fleet(root: str | Path, robot: str = "puma560", robots: int = 20,
                   sessions: int = 2, poses: int = 50, noise: float = 1e-5,
                   drifted: int = 2, broken: int = 1, drift_sigma: float = 10.0,
                   seed: int = 0, start: str = "2026-01-05", interval_days: int = 91,
                   length_error: float = 5e-4, angle_error: float = math.radians(0.05),
                   offset_error: float = math.radians(0.1), fleet: str = "simulated"
                   ) -> SimulatedFleet:
    """Write a simulated fleet under ``root`` (see the module docstring).

    Args:
        robot: the model (built-in name, YAML or URDF path).
        robots, sessions, poses: counts (``sessions >= 2`` for drift).
        noise: tracker noise per coordinate [m].
        drifted, broken: robots with a drift between their last two sessions / with an
            unreadable last-session file (the first robots after shuffling by ``seed``).
        drift_sigma: size of each drift in predicted combined standard errors.
        start, interval_days: date of the first session and days between sessions.
        length_error, angle_error, offset_error: standard deviations of each robot's
            own errors [m, rad, rad].
    """
    import yaml

    from kincal.measure.registry import simulate_measurements, write_measurements
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.chain import ROLES, Robot
    from kincal.workflow.robots import load_any_robot

    if robots < 1 or sessions < 1 or poses < 1:
        raise KincalError("a simulated fleet needs at least 1 robot, 1 session and 1 pose")
    if drifted + broken > robots:
        raise KincalError(f"--drifted {drifted} + --broken {broken} is more than the "
                          f"{robots} robots")
    if drifted and sessions < 2:
        raise KincalError("--drifted needs at least 2 sessions per robot")
    try:
        day0 = _dt.date.fromisoformat(start)
    except ValueError:
        raise KincalError(f"option --start: {start!r} is not a date YYYY-MM-DD") from None
    nominal = load_any_robot(robot)
    if not isinstance(nominal, Robot):
        raise KincalError("simulated fleets are of serial robots")
    root = Path(root)
    order = np.random.default_rng([seed, 2**31]).permutation(robots)
    drift_set = {int(k) for k in order[:drifted]}
    broken_set = {int(k) for k in order[drifted:drifted + broken]}
    dates = [(day0 + _dt.timedelta(days=interval_days * s)).isoformat() for s in range(sessions)]
    units = {"length": "mm", "angle": "deg"}
    manifest_robots, truth = [], []
    for k in range(robots):
        rng = np.random.default_rng([seed, k])
        serial = serial_name(k)
        true = perturb_robot(nominal, rng, length_std=length_error, angle_std=angle_error,
                             offset_std=offset_error, base_std=(length_error, angle_error),
                             tool_std=(length_error, angle_error))
        info: dict[str, Any] = {"serial": serial, "dates": dates, "drift": None,
                                "broken": None,
                                "true_parameters": dict(zip(true.param_names,
                                                            true.param_values.tolist(),
                                                            strict=True))}
        entries = []
        first_design: tuple[list[Any], dict[str, float]] = ([], {})
        for s, date in enumerate(dates):
            if s == sessions - 1 and k in drift_set:
                info["drift"], true = _drift(true, first_design, rng, drift_sigma, ROLES,
                                             {"m": length_error, "rad": angle_error,
                                              "offset": offset_error})
                info["drift"]["from"], info["drift"]["to"] = dates[s - 1], date
            blocks, inst_truth = simulate_measurements("position", true, rng, poses, noise)
            if s == 0:
                first_design = (blocks, inst_truth)
            folder = root / serial / date
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / "tracker.csv"
            write_measurements("position", blocks, path, units, nominal)
            if s == sessions - 1 and k in broken_set:
                info["broken"] = {"date": date, "file": str(path.relative_to(root)),
                                  "line": _corrupt(path, rng)}
            entries.append({"date": date, "data": [f"{serial}/{date}/tracker.csv"]})
        manifest_robots.append({"serial": serial, "sessions": entries})
        truth.append(info)
    manifest = root / "fleet.yaml"
    doc = {"fleet": fleet, "defaults": {"robot": robot}, "robots": manifest_robots}
    head = (f"# kincal fleet manifest: {robots} simulated {nominal.name} robot(s), {sessions} "
            f"session(s) each, {poses} poses, tracker noise {noise * 1e3:g} mm (seed {seed})\n")
    atomic_write_text(manifest, head + yaml.safe_dump(doc, sort_keys=False,
                                                      default_flow_style=None, width=100))
    truth_path = root / "truth.json"
    atomic_write_text(truth_path, json.dumps(
        {"robot": robot, "robots": robots, "sessions": sessions, "poses": poses,
         "noise_m": noise, "seed": seed, "drift_sigma": drift_sigma, "fleet": truth},
        indent=1) + "\n")
    return SimulatedFleet(root, manifest, truth_path, truth)


def _drift(true: Any, design: tuple[list[Any], dict[str, float]], rng: np.random.Generator,
           size: float, roles: tuple[str, ...], scale: dict[str, float]
           ) -> tuple[dict[str, Any], Any]:
    """Move one identifiable joint parameter (not base / tool) of ``true`` by ``size``
    predicted combined standard errors; only parameters whose drift stays within three
    times their role's manufacturing error (``scale``: ``offset``, ``m``, ``rad``) are
    drawn, so a drift is a plausible knock, not a broken robot."""
    blocks, inst_truth = design
    truth = {**dict(zip(true.param_names, true.param_values.tolist(), strict=True)),
             **inst_truth}
    sig = predicted_std(true, blocks, truth)
    role = dict(zip(true.param_names, true.param_roles, strict=True))
    unit = dict(zip(true.param_names, true.param_units, strict=True))

    def cap(n: str) -> float:
        return 3.0 * (scale["offset"] if role[n] == "offset" and unit[n] == "rad"
                      else scale[unit[n]])

    pick = [n for n in sig if role.get(n) in roles and role[n] not in ("base", "tool")
            and size * math.sqrt(2.0) * sig[n] <= cap(n)]
    if not pick:
        raise KincalError(f"no identifiable joint parameter can drift by {size:g} σ within "
                          "three times its manufacturing error: lower --drift-sigma or "
                          "measure more poses")
    name = pick[int(rng.integers(len(pick)))]
    sigma_c = math.sqrt(2.0) * sig[name]
    change = float(rng.choice([-1.0, 1.0]) * size * sigma_c)
    i = true.param_names.index(name)
    values = true.param_values.copy()
    values[i] += change
    return ({"parameter": name, "change": change, "unit": unit[name],
             "sigma_combined": sigma_c, "sigmas": size}, true.with_params(values))
