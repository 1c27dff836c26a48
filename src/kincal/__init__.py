"""kincal: kinematic calibration of robot manipulators."""

from __future__ import annotations

from kincal._version import __version__

__all__ = ["__version__"]
