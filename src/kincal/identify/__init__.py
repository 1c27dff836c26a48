"""Identification: which parameters the data can see, their estimate and its certainty.

* :mod:`~kincal.identify.identifiability` - zero and dependent columns, the base
  parameter set, condition numbers, in sentences;
* :mod:`~kincal.identify.solver` - iterative least squares / Levenberg-Marquardt on
  the stacked system, stages, robust losses, priors;
* :mod:`~kincal.identify.uncertainty` - covariance and standard errors;
  :mod:`~kincal.identify.accuracy` - the covariance propagated to predicted positions;
* :mod:`~kincal.identify.validation` - held-out errors and cross-validation;
* :mod:`~kincal.identify.observability`, :mod:`~kincal.identify.design`,
  :mod:`~kincal.identify.prediction` - choosing poses before measuring;
* :mod:`~kincal.identify.staged_selection` - condition-number data selection and staged
  least squares (cross-bar artifacts).

Layer rule: imports :mod:`kincal.measure` and everything below it, nothing above.
"""
