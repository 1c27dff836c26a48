"""The calibration history as files: CSV (one row per calibration, or per parameter) and
JSON (every record in full).

* :func:`history_csv` - one row per calibration: serial, session date, status, reason,
  kincal version, fingerprint, iterations, sigma0, position RMS on training / held-out /
  CV [mm], then one ``<parameter> [mm|deg]`` column per robot parameter estimate;
* :func:`parameters_csv` - one row per (calibration, parameter): estimate and standard
  error in the parameter's SI unit (m, rad), as stored;
* :func:`history_json` - every record with its parameters, covariance (SI) and metrics.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from typing import Any

from kincal.robots.chain import ROLES
from kincal.units import display_scale

__all__ = ["history_csv", "parameters_csv", "history_json"]

_SUMMARY = ("id", "fleet", "serial", "date", "status", "reason", "kincal_version",
            "created_at", "fingerprint", "robot", "iterations", "sigma0")


def history_csv(records: Sequence[Mapping[str, Any]]) -> str:
    """One row per calibration (see the module docstring); RMS in mm, estimates in mm/deg."""
    names: dict[str, str] = {}
    for r in records:
        for p in r["parameters"]:
            if p["role"] in ROLES and p["name"] not in names:
                names[p["name"]] = p["unit"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*_SUMMARY, "rms_train_mm", "rms_validation_mm", "rms_cv_mm",
                *(f"{n} [{display_scale(u)[1]}]" for n, u in names.items())])
    for r in records:
        est = {p["name"]: p["estimate"] for p in r["parameters"]}
        w.writerow([*("" if r.get(k) is None else r.get(k) for k in _SUMMARY),
                    *("" if r.get(k) is None else f"{r[k] * 1e3:.6g}"
                      for k in ("rms_train_m", "rms_validation_m", "rms_cv_m")),
                    *("" if n not in est else f"{est[n] * display_scale(u)[0]:.10g}"
                      for n, u in names.items())])
    return buf.getvalue()


def parameters_csv(records: Sequence[Mapping[str, Any]]) -> str:
    """One row per (calibration, parameter), SI units."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["id", "serial", "date", "parameter", "unit", "role", "nominal", "estimate",
                "std", "estimated", "identifiable"])
    for r in records:
        for p in r["parameters"]:
            w.writerow([r["id"], r["serial"], r["date"], p["name"], p["unit"], p["role"],
                        repr(p["nominal"]), repr(p["estimate"]),
                        "" if p["std"] is None else repr(p["std"]), int(bool(p["estimated"])),
                        int(bool(p["identifiable"]))])
    return buf.getvalue()


def history_json(records: Sequence[Mapping[str, Any]]) -> str:
    """Every record in full (parameters, covariance over ``estimated``, metrics), SI."""
    out = []
    for r in records:
        d = {k: v for k, v in r.items() if k != "covariance"}
        d["covariance"] = r["covariance"].tolist() if hasattr(r.get("covariance"), "tolist") \
            else r.get("covariance")
        out.append(d)
    return json.dumps({"units": "SI (m, rad)", "records": out}, indent=1) + "\n"
