"""What a command that takes a calibrated robot says about its envelope.

A calibrated robot file carries its training region and accuracy model
(:mod:`kincal.identify.envelope`); ``fk`` and ``ik`` use it at the configurations they
compute: the predicted error there, and one loud warning (on stderr when the JSON goes
to stdout) when a configuration lies outside the training region.
"""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.markup import escape

__all__ = ["envelope_report"]


def envelope_report(out: Console, robot: Any, q: Any, what: str,
                    unit: tuple[float, str] = (1e3, "mm"), quiet: bool = False
                    ) -> dict[str, Any] | None:
    """Print the predicted error of ``robot`` at the configurations ``q`` from the envelope
    it carries (unless ``quiet``) and a warning when any lies outside the training region
    (always); return the JSON entry ``{"predicted_error_m", "outside_training_region",
    "warning"}``, or None when the robot carries no envelope."""
    if robot.meta.get("calibration") is None:      # no envelope: nothing heavy to import
        return None
    import numpy as np

    from kincal.identify.envelope import outside_line, predict_with_envelope

    pred = predict_with_envelope(robot, np.atleast_2d(np.asarray(q, dtype=float)))
    if pred is None:
        return None
    f, u = unit
    if not quiet:
        out.print(f"predicted error (calibration envelope): "
                  f"{', '.join(f'{v * f:.3g}' for v in pred.predicted_m)} {u}")
    line = outside_line(pred, what, robot.name, unit)
    if line:
        out.print(f"[bold yellow]warning[/bold yellow]: {escape(line)}")
    return {"predicted_error_m": pred.predicted_m.tolist(),
            "outside_training_region": pred.outside.tolist(), "warning": line}
