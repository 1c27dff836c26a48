"""Identification: which parameters the data can see, their estimate and its certainty.

* :mod:`~kincal.identify.identifiability` - zero and dependent columns, the base
  parameter set, condition numbers, in sentences;
* :mod:`~kincal.identify.solver` - :func:`~kincal.identify.solver.calibrate`: the stages,
  base-set choice, noise scale and statistics around the iteration, which lives in
  :mod:`~kincal.identify.stage` (one stage), :mod:`~kincal.identify.gauss_newton` and
  :mod:`~kincal.identify.levenberg_marquardt` (one method each),
  :mod:`~kincal.identify.linearisation` (the triangle and residual reuse),
  :mod:`~kincal.identify.stopping` / :mod:`~kincal.identify.status` (the rules and why a
  stage stopped), :mod:`~kincal.identify.robust` (losses), :mod:`~kincal.identify.prior`
  (MAP rows), :mod:`~kincal.identify.reselection` (the set checked at the solution);
  :mod:`~kincal.identify.result` the :class:`~kincal.identify.result.CalibrationResult`;
* :mod:`~kincal.identify.uncertainty` - covariance and standard errors;
  :mod:`~kincal.identify.accuracy` - the covariance propagated to predicted positions;
* :mod:`~kincal.identify.validation` - held-out errors and cross-validation;
* :mod:`~kincal.identify.observability`, :mod:`~kincal.identify.design`,
  :mod:`~kincal.identify.prediction` - choosing poses before measuring;
* :mod:`~kincal.identify.staged_selection` - condition-number data selection and staged
  least squares (cross-bar artifacts).

Layer rule: imports :mod:`kincal.measure` and everything below it, nothing above.
"""
