"""The calibration history's tables (SQLAlchemy Core; SQLite, PostgreSQL or any SQL server).

Schema version :data:`SCHEMA_VERSION`, kept in ``kincal_schema``.  Portable types only:
dates are ISO text (``YYYY-MM-DD``; times UTC ``YYYY-MM-DDTHH:MM:SSZ``), JSON is text,
the covariance is a binary little-endian float64 matrix.

``calibrations`` - one row per calibration of one robot session:

=====================  ======================================================
serial, session_date    the robot and the day it was measured
fingerprint             SHA-256 of the inputs (:func:`kincal.fleet.tasks.fingerprint`)
status, reason          ``ok`` / ``not converged`` / ``untrusted`` / ``failed``, why
kincal_version          the kincal that computed it; ``created_at`` when (UTC)
robot, options, files   the robot spec, the options (JSON), data / held-out files (JSON)
converged, iterations   the solver's outcome; ``sigma0`` the a-posteriori variance factor
rms_*_m                 position RMS [m] on training, held-out files, CV folds
metrics, warnings       everything of the result JSON's ``metrics``; warnings (JSON)
estimated, covariance   names (JSON) and their covariance (p x p float64) [m, rad]
=====================  ======================================================

``parameters`` - one row per parameter of a calibration (name, unit, role, nominal,
estimate, std (NULL when not estimated), estimated, identifiable), SI units.

``crosschecks`` - the previous calibration of a robot measured on a later session's
data (``rms_position_m`` and the full metrics).
"""

from __future__ import annotations

from sqlalchemy import (
    Boolean,
    Column,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
)

__all__ = ["SCHEMA_VERSION", "metadata", "schema_table", "calibrations", "parameters",
           "crosschecks"]

#: Bump with every change of the tables; :mod:`kincal.fleet.store` refuses newer files.
SCHEMA_VERSION = 1

metadata = MetaData()

schema_table = Table(
    "kincal_schema", metadata,
    Column("version", Integer, nullable=False),
)

calibrations = Table(
    "calibrations", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("fleet", String(200), nullable=False, default=""),
    Column("serial", String(200), nullable=False, index=True),
    Column("session_date", String(10), nullable=False),
    Column("fingerprint", String(64), nullable=False),
    Column("status", String(20), nullable=False),
    Column("reason", Text),
    Column("kincal_version", String(40), nullable=False),
    Column("created_at", String(20), nullable=False),
    Column("robot", Text, nullable=False),
    Column("options", Text, nullable=False),
    Column("files", Text, nullable=False),
    Column("converged", Boolean, nullable=False),
    Column("iterations", Integer),
    Column("sigma0", Float),
    Column("seconds", Float),
    Column("rms_train_m", Float),
    Column("rms_validation_m", Float),
    Column("rms_cv_m", Float),
    Column("metrics", Text, nullable=False),
    Column("warnings", Text, nullable=False),
    Column("estimated", Text, nullable=False),
    Column("covariance", LargeBinary),
    Column("worker", String(200)),
    UniqueConstraint("serial", "session_date", "fingerprint", name="one_record_per_input"),
)

parameters = Table(
    "parameters", metadata,
    Column("calibration_id", Integer, ForeignKey("calibrations.id", ondelete="CASCADE"),
           primary_key=True),
    Column("name", String(200), primary_key=True),
    Column("unit", String(20), nullable=False),
    Column("role", String(40), nullable=False),
    Column("nominal", Float, nullable=False),
    Column("estimate", Float, nullable=False),
    Column("std", Float),
    Column("estimated", Boolean, nullable=False),
    Column("identifiable", Boolean, nullable=False),
)

crosschecks = Table(
    "crosschecks", metadata,
    Column("calibration_id", Integer, ForeignKey("calibrations.id", ondelete="CASCADE"),
           primary_key=True),
    Column("previous_id", Integer, ForeignKey("calibrations.id", ondelete="CASCADE"),
           primary_key=True),
    Column("status", String(20), nullable=False),
    Column("reason", Text),
    Column("rms_position_m", Float),
    Column("metrics", Text, nullable=False),
)
