"""The version of kincal, in one place (the package face and the report read it)."""

__version__ = "0.1.0"
