"""Fleet calibration: many robots, a calibration history in a database, drift alarms.

One calibration task per robot session (:mod:`~kincal.fleet.tasks`: the same
:func:`~kincal.workflow.session.read_session` + :func:`~kincal.workflow.flow.run_flow` as
``kincal calibrate``, as a pure function: inputs in, a result record out), run on Dask
distributed (:mod:`~kincal.fleet.engine`: an embedded ``LocalCluster`` or a scheduler
address) or in-process, stored one transaction per record in a SQLAlchemy database
(:mod:`~kincal.fleet.schema`, :mod:`~kincal.fleet.store`: SQLite by default, any URL such
as PostgreSQL), compared session to session (:mod:`~kincal.fleet.drift`) and shown on
one HTML page (:mod:`~kincal.fleet.page`).  :mod:`~kincal.fleet.manifest` reads the
fleet manifest (the setup-file schema of ``docs/conventions.md``) or a
``<serial>/<date>/*.csv`` folder; :mod:`~kincal.fleet.simulate` writes simulated fleets;
:mod:`~kincal.fleet.run` ties tasks, engine and store together; :mod:`~kincal.fleet.export`
writes the history as CSV / JSON.

Needs the ``fleet`` extra (``dask[distributed]``, SQLAlchemy), imported only here; no
other layer imports this package except the command line (lazily, inside commands).

Layer rule: may import every layer below it (workflow and everything under it); never
the command line.
"""
