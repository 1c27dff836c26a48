"""kincal: kinematic calibration of robot manipulators."""

from __future__ import annotations

__version__ = "0.1.0"
