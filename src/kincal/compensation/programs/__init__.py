"""Robot programs through a calibrated model: one small reader per controller language.

* :mod:`~kincal.compensation.programs.krl` - KUKA KRL (``.src`` + ``.dat``);
* :mod:`~kincal.compensation.programs.rapid` - ABB RAPID (``.mod``, ``.prg``);
* :mod:`~kincal.compensation.programs.urscript` - Universal Robots URScript (``.script``);
* :mod:`~kincal.compensation.programs.fanuc` - FANUC TP ASCII (``.ls``).

:mod:`~kincal.compensation.programs.sequence` resolves the targets that take part of
their value from the previous position (KRL partial aggregates).

Each reader returns the file texts and :class:`~kincal.compensation.programs.base.ProgramTarget`
values that know where their numbers are; :mod:`~kincal.compensation.programs.driver`
turns them into flange poses, runs :func:`kincal.compensation.filter.filter_targets` and
writes the numbers back (:mod:`~kincal.compensation.programs.numbers`).
"""
