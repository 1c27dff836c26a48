"""The calibration report: error metrics, the result JSON, plots and the HTML page.

:mod:`~kincal.report.metrics` computes the numbers every output shows (RMS / max
errors before and after, the JSON document); :mod:`~kincal.report.plots` and
:mod:`~kincal.report.artifact_plots` draw the figures (matplotlib, PNG bytes);
:mod:`~kincal.report.html` writes one self-contained HTML file.

Layer rule: imports :mod:`kincal.identify` and everything below it; never the
workflow or the command line.
"""
