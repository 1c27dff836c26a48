"""The bar-length figures: bar lengths from the joint readings, nominal vs calibrated."""

from __future__ import annotations

import numpy as np

from kincal.identify.solver import calibrate
from kincal.measure.artifacts import ArtifactGeometry, Probe, simulate_artifact
from kincal.measure.simulate import perturb_robot
from kincal.report.artifact_plots import (
    length_summary,
    plot_lengths,
    save_length_error_figures,
)
from kincal.robots.files import load_serial_robot


def test_figures_4_and_5(tmp_path):
    import matplotlib.image as mpimg

    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    true = perturb_robot(nominal, rng)
    b, _ = simulate_artifact(true, ArtifactGeometry.cross_bar(0.3), 12, rng,
                             Probe.length(0.1), joint_std=np.radians(0.001),
                             model_robot=nominal, name="cross")
    res = calibrate(nominal, [b])
    files = save_length_error_figures(b, nominal, res.robot, tmp_path / "figs")
    for f in files.values():
        img = mpimg.imread(f)
        assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 400
    before, after = length_summary(b, nominal), length_summary(b, res.robot)
    assert before["rms_length_error_m"] > 20 * after["rms_length_error_m"]
    assert before["rms_angle_deviation_rad"] > 20 * after["rms_angle_deviation_rad"]
    fig = plot_lengths(b, res.robot)
    ax = fig.axes[0]
    # the plotted length errors are the block's, in mm, one series per arm
    plotted = np.concatenate([ln.get_ydata() for ln in ax.lines if len(ln.get_ydata()) > 2])
    np.testing.assert_allclose(np.sort(plotted), np.sort(b.lengths(res.robot).error * 1e3))
    assert len(fig.axes) == 2                          # lengths and the right angle
