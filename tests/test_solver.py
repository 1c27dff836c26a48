"""The solver: exact recovery from noise-free data, methods, stages, selection, robust
losses, rank-deficient requests, result objects."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.identifiability import analyze
from kincal.identify.solver import Calibration, CalibrationResult, calibrate, match_names
from kincal.measure.base import StackedProblem, stack
from kincal.measure.instruments.pose import simulate_poses
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.dh import dh_links, from_dh
from kincal.robots.files import load_serial_robot

INSTRUMENT = [1.5, 0.4, -0.2, 2.0, -0.15, 0.1]
MARKER = [0.03, -0.02, 0.06]
TARGET = [0.01, 0.02, 0.05, 0.3, -0.1, 0.2]


def puma():
    return from_dh(dh_links(load_serial_robot("puma560")), name="puma560",
                   tool=[0.0, 0.0, 0.08, 0, 0, 0])


def stanford():
    """The library Stanford arm (RRPRRR, prismatic third joint) with a tool offset."""
    return load_serial_robot("stanford").with_params({"tool.z": 0.05})


def make_block(true, q, rng, kind, noise=0.0):
    if kind == "pose":
        return simulate_poses(true, q, rng, noise, noise, INSTRUMENT, TARGET)
    return simulate_positions(true, q, rng, noise, INSTRUMENT, MARKER)


def tight_minimum(res):
    """scipy's least_squares from the result's start over its estimated parameters, with
    the tightest tolerances and the analytic Jacobian: the exact minimum to compare with."""
    from scipy.optimize import least_squares

    prob, th0 = res.problem, res.theta0
    est = [prob.names.index(n) for n in res.estimated]

    def fun(x, jac=False):
        th = th0.copy()
        th[est] = x
        return prob.residuals_and_jacobian(th)[1][:, est] if jac else prob.residuals(th)

    return est, least_squares(fun, th0[est], jac=lambda x: fun(x, True), x_scale="jac",
                              xtol=1e-15, ftol=1e-15, gtol=1e-15).x


def base_set(robot, kind, q, rng):
    """The robot parameters the automatic selection will estimate (analysed at nominal)."""
    prob, theta = stack(robot, [make_block(robot, q, rng, kind)])
    _, J = prob.residuals_and_jacobian(theta)
    rep = analyze(J, prob.names, roles=prob.roles)
    return [n for n in rep.identifiable if n in robot.param_names]


def truth_of(true, kind):
    inst = np.asarray(INSTRUMENT)
    tail = np.asarray(TARGET) if kind == "pose" else np.asarray(MARKER)
    return dict(true.params()), np.concatenate([inst, tail])


@pytest.mark.parametrize("robot_fn,kind", [(puma, "pose"), (puma, "position"),
                                           (stanford, "position"), (stanford, "pose")])
@pytest.mark.parametrize("method", ["lm", "gauss-newton"])
def test_noise_free_recovery(robot_fn, kind, method):
    rng = np.random.default_rng(7)
    robot = robot_fn()
    q = random_configurations(robot, 40, rng)
    names = base_set(robot, kind, q, rng)
    true = perturb_robot(robot, rng, names=names)
    res = calibrate(robot, [make_block(true, q, rng, kind)], method=method)
    assert res.converged, res.message
    assert sorted(n for n in res.estimated if n in robot.param_names) == sorted(names)
    tp, tb = truth_of(true, kind)
    err = {n: abs(res.params[n] - tp[n]) for n in names}
    blk = res.theta[robot.num_params:]
    err.update({n: abs(v) for n, v in zip(res.names[robot.num_params:], blk - tb, strict=True)})
    worst = max(err, key=err.get)
    print(f"\n{robot.name} {kind} {method}: {len(res.estimated)} estimated in "
          f"{res.iterations} iterations, worst error {worst} {err[worst]:.2e}")
    assert err[worst] < 1e-9, f"{worst} off by {err[worst]:.2e}"
    # the calibrated robot reproduces the true one wherever the data can see it
    q2 = random_configurations(robot, 20, rng)
    check = make_block(true, q2, rng, kind)
    e = check.errors(res.robot, blk)["position_m"]
    assert e.max() < 1e-9


def test_gauss_newton_is_the_lecture_iteration():
    """First GN step = pinv(Phi) dr with Phi, dr at the starting point (lecture 000)."""
    rng = np.random.default_rng(8)
    robot = puma()
    q = random_configurations(robot, 30, rng)
    true = perturb_robot(robot, rng, names=base_set(robot, "pose", q, rng))
    blk = make_block(true, q, rng, "pose")
    res = calibrate(robot, [blk], method="gauss-newton", max_iter=1)
    prob, theta0 = stack(robot, [blk])
    r, J = prob.residuals_and_jacobian(theta0)
    est = [prob.names.index(n) for n in res.estimated]
    dphi = -np.linalg.pinv(J[:, est]) @ r
    assert np.allclose(res.history[1].theta[est] - theta0[est], dphi, rtol=1e-8, atol=1e-14)


def test_lm_and_gauss_newton_agree_with_noise():
    rng = np.random.default_rng(9)
    robot = puma()
    q = random_configurations(robot, 40, rng)
    true = perturb_robot(robot, rng)
    blk = make_block(true, q, rng, "position", noise=2e-5)
    a = calibrate(robot, [blk], method="lm")
    b = calibrate(robot, [blk], method="gauss-newton")
    assert a.converged and b.converged
    assert a.estimated == b.estimated
    diff = np.abs(a.theta - b.theta)
    # both stop when the step is below tol_step = 1e-10 (1 + |x|): they agree to that
    # level, a thousandth of the statistical uncertainty
    assert np.all(diff <= 1e-3 * a.std + 1e-9)
    assert np.max(diff[a.std > 0] / a.std[a.std > 0]) < 1e-3
    assert a.sigma0 == pytest.approx(b.sigma0, rel=1e-9)
    assert 0.7 < a.sigma0 < 1.3                        # the stated sigma is the true noise


def test_free_fixed_stages_and_progress():
    rng = np.random.default_rng(10)
    robot = puma()
    q = random_configurations(robot, 30, rng)
    true = perturb_robot(robot, rng)
    blk = make_block(true, q, rng, "position", noise=1e-5)
    seen = []
    res = calibrate(robot, [blk], free=["theta_offset[*]", "tracker.*"], fixed=["tracker.marker.z"],
                    stages=["offsets", "all"], progress=seen.append)
    assert "tracker.marker.z" not in res.estimated and "a[2]" not in res.estimated
    allowed = {res.names[i] for i in match_names(res.names, ["theta_offset[*]", "tracker.*"])}
    assert set(res.estimated) <= allowed
    assert [s for s, _ in res.stages] == ["offsets", "all"]
    assert {h.stage for h in res.history} == {"offsets", "all"}
    assert len(seen) == len(res.history) and seen[0].iteration == 0
    # theta_offset[1] was requested but is not identifiable with a free tracker frame
    assert "theta_offset[1]" in res.identifiability.dependent
    assert "not identifiable" in res.message
    with pytest.raises(KincalError, match="did you mean"):
        calibrate(robot, [blk], free=["theta_ofset[2]"])
    with pytest.raises(KincalError, match="unknown method"):
        calibrate(robot, [blk], method="newton")
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(KincalError, match="loss_scale must be a positive finite"):
            calibrate(robot, [blk], loss="huber", loss_scale=bad)
    assert match_names(["theta_offset[1]", "d[1]", "theta_offset[2]"], "theta_offset[*]") == [0, 2]


def test_rank_deficient_request_is_named_and_held():
    """free= everything from position data: no NaN, no wild numbers, dependents named."""
    rng = np.random.default_rng(11)
    robot = puma()
    q = random_configurations(robot, 30, rng)
    true = perturb_robot(robot, rng)
    blk = make_block(true, q, rng, "position", noise=1e-5)
    res = calibrate(robot, [blk], free=["*"])
    assert res.converged
    assert np.all(np.isfinite(res.theta)) and np.all(np.isfinite(res.std))
    assert np.all(np.isfinite(res.covariance))
    rep = res.identifiability
    held = rep.not_identifiable
    assert {"d[3]", "base.x", "tool.x", "theta_offset[1]"} <= set(held)
    assert rep.dependent["d[3]"] == ["d[2]"]
    for n in held:
        i = res.names.index(n)
        assert res.theta[i] == res.theta0[i] and res.std[i] == 0.0
        assert n not in res.estimated
    # every estimate moved by a plausible amount (the true errors are ~1 mm / 0.1 deg)
    moved = np.abs(res.theta - res.theta0)[: robot.num_params]
    assert moved.max() < 0.05
    d = res.to_dict()
    json.dumps(d)
    by = {p["name"]: p for p in d["parameters"]}
    assert by["d[3]"]["std"] is None and by["d[3]"]["identifiable"] is False
    assert by["a[2]"]["estimated"] is True and by["a[2]"]["std"] > 0
    assert d["identifiable_count"] == len(rep.identifiable)
    text = res.summary(all_parameters=True)
    assert "d[3]" in text and "dependent on d[2]" in text


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_losses_flag_outliers(loss):
    rng = np.random.default_rng(12)
    robot = puma()
    q = random_configurations(robot, 50, rng)
    true = perturb_robot(robot, rng)
    blk = make_block(true, q, rng, "position", noise=1e-5)
    bad = [3, 17, 31]
    blk.positions[bad] += np.array([4e-3, -3e-3, 5e-3])        # 5 mm gross errors
    blk._y[bad, 0] = blk.positions[bad]
    clean = calibrate(robot, [blk], loss=loss)
    assert sorted(r for _, r in clean.outliers) == bad
    assert all(b == "tracker" for b, _ in clean.outliers)
    plain = calibrate(robot, [blk])
    assert plain.outliers == []
    # robust fit: the other measurements are fitted at the noise level
    e = clean.errors()["tracker"]["position_m"]
    good = np.setdiff1d(np.arange(50), bad)
    assert np.sqrt(np.mean(e[good] ** 2)) < 4 * np.sqrt(3) * 1e-5
    assert np.sqrt(np.mean(plain.errors()["tracker"]["position_m"][good] ** 2)) > 1e-4


def test_result_objects_and_estimator():
    rng = np.random.default_rng(13)
    robot = puma()
    q = random_configurations(robot, 25, rng)
    blk = make_block(perturb_robot(robot, rng), q, rng, "pose", noise=1e-5)
    est = Calibration(robot, stages=["offsets", "all"])
    assert "Calibration('puma560'" in repr(est)
    assert est.fit(blk) is est
    res = est.result_
    assert isinstance(res, CalibrationResult)
    assert repr(res).startswith("CalibrationResult(converged=True")
    assert set(res.block_values("tracker")) == set(res.names[robot.num_params:])
    assert res.correlation.shape == (len(res.estimated),) * 2
    assert np.allclose(np.diag(res.correlation), 1.0)
    assert res.robot.num_params == robot.num_params and res.robot_initial is robot
    assert res.residuals.shape == (25 * 6,)
    rms = res.rms()
    assert set(rms) == {"rms_position_m", "rms_orientation_rad"}
    assert rms["rms_position_m"] < 5e-5
    d = res.to_dict()
    assert {"parameters", "identifiable_count", "converged", "iterations", "sigma0", "history",
            "identifiability"} <= set(d)
    json.dumps(d)
    assert "estimated" in res.summary()


# --------------------------------------------------------------------------- identifiability
def test_gauss_newton_holds_the_scale_of_unknown_planes():
    """Contacts with planes of unknown offset cannot see the scale: J v = r for the
    direction that shrinks the robot, the marker and the planes together.  Gauss-Newton
    jumps along it to a zero-size robot ("converged", zero residual, a collapsed base
    set); the solver names d[4] (the last length of that direction) and solves again
    without it: the set of the noise-free analysis, the truth within its std."""
    from test_instruments_support import NOMINAL, cases, scenario

    sim, n, opts, noise = cases()["plane"]
    sc = scenario(sim, n, 11, noise, **opts)
    blocks, _ = sim(sc.true, np.random.default_rng(11), n, noise, **opts)
    res = calibrate(NOMINAL, blocks, method="gauss-newton")
    assert res.converged and 0.7 < res.sigma0 < 1.3, res.message
    assert sorted(res.estimated) == sorted(sc.free)
    assert "d[4] only rescale(s) the residuals" in res.message
    by = {p["name"]: p for p in res.to_dict()["parameters"]}
    assert by["d[4]"]["status"].startswith("dependent on") and not by["d[4]"]["identifiable"]
    assert res.params["d[4]"] == NOMINAL.params()["d[4]"]
    est = [res.names.index(p) for p in res.estimated]
    z = (res.theta[est] - np.array([sc.truth[p] for p in res.estimated])) / res.std[est]
    assert np.max(np.abs(z)) < 4.5


def test_a_stage_stopped_by_max_iter_keeps_its_set():
    """A consistent linear model has r in the range of J everywhere (a residual-
    rescaling direction for the test); stopped by max_iter it must keep every
    parameter: solving without one does not converge either, so nothing changes."""
    from test_solver_prior import ROBOT, LinearBlock

    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, 4))
    blk = LinearBlock(A, A @ np.array([0.1, -0.2, 0.05, 0.3]))
    res = calibrate(ROBOT, [blk], max_iter=1)
    assert not res.converged and res.iterations == 1 and len(res.history) == 2
    assert res.estimated == [f"lin.b{j}" for j in range(4)]
    full = calibrate(ROBOT, [blk])
    assert full.converged and full.estimated == res.estimated
    assert np.allclose(full.theta[-4:], [0.1, -0.2, 0.05, 0.3], rtol=1e-12)


# --------------------------------------------------------------------------- termination
def test_levenberg_marquardt_stops_with_one_failed_trial():
    """At the minimum the last trial step fails and is already shorter than tol_step:
    the stage ends there (one residual evaluation per iteration in all), at the
    solution scipy's least_squares finds with the tightest tolerances."""
    rng = np.random.default_rng(7)
    robot = puma()
    q = random_configurations(robot, 40, rng)
    blk = make_block(perturb_robot(robot, rng), q, rng, "pose", noise=1e-5)
    calls = [0]
    evaluate = blk.evaluate

    def counted(robot, extra, jacobian=True):
        calls[0] += not jacobian
        return evaluate(robot, extra, jacobian)

    blk.evaluate = counted
    res = calibrate(robot, [blk], tol_std=0.0)         # the step rules alone
    # Which of the two step rules ends the stage depends on the last bits of the BLAS in
    # use (the last accepted step may already be below tol_step); either way no trial
    # evaluation may be wasted at the minimum.
    assert res.converged and ("no descent step longer than tol_step" in res.message
                              or "step below tol_step" in res.message), res.message
    assert calls[0] <= res.iterations                  # was 11 extra at the last iteration
    est, ref = tight_minimum(res)
    assert np.max(np.abs(res.theta[est] - ref) / (1 + np.abs(ref))) < 1e-10


@pytest.mark.parametrize("noise", [1e-5, 1e-3])
def test_stage_stops_within_tol_std_standard_errors(noise, monkeypatch):
    """The default stop: the remaining Gauss-Newton step is at most ``tol_std`` standard
    errors long, so the estimate is that close to the exact minimum (scipy's, with the
    tightest tolerances) in every parameter, and the stage saves the linearisations the
    step rules would still build.  Also with stated sigmas 100x too small (noise 1 mm,
    sigma 10 um): the distance is measured in the smaller of the stated and the
    a-posteriori standard errors."""
    rng = np.random.default_rng(11)
    robot = puma()
    true = perturb_robot(robot, rng)
    blk = make_block(true, random_configurations(robot, 200, rng), rng, "position",
                     noise=noise)
    if noise > 1e-5:                                    # stated 10 um, measured 1 mm
        blk = PositionMeasurement(blk.q, blk._y, 1e-5, blk.name)
    builds = [0]
    compressed = StackedProblem.compressed

    def counted(self, *args, **kw):
        builds[0] += 1
        return compressed(self, *args, **kw)

    monkeypatch.setattr(StackedProblem, "compressed", counted)
    res = calibrate(robot, [blk])
    n_default = builds[0]
    builds[0] = 0
    tight = calibrate(robot, [blk], tol_std=0.0)
    n_tight = builds[0]
    assert res.converged and "below tol_std = 0.001 standard errors" in res.message
    # stated sigmas 100x too small: the rule measures in them, 100x stricter than the
    # a-posteriori standard errors, and saves nothing here
    assert n_default < n_tight if noise <= 1e-5 else n_default <= n_tight, (n_default, n_tight)
    assert res.estimated == tight.estimated
    est, ref = tight_minimum(res)
    # the standard errors the rule measures in: sigma0 = min(a-posteriori, 1)
    se = res.std[est] / res.sigma0 * min(res.sigma0, 1.0)
    assert np.max(np.abs(res.theta[est] - ref) / se) <= 1e-3
    # without the rule the step rules hold it to tol_step (1e-10 relative)
    assert np.max(np.abs(tight.theta[est] - ref) / (1 + np.abs(ref))) < 1e-10
    # the residuals kept with the last triangle are those at the returned estimate
    assert np.allclose(res.residuals, res.problem.residuals(res.theta), rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- summary
def test_summary_shows_every_error_kind_in_its_unit():
    from test_solver_prior import ROBOT, LinearBlock

    from kincal.identify.solver import format_error

    class Reporting(LinearBlock):
        def errors(self, robot, extra):
            return {"image_px": np.array([3.0, 4.0]), "range_m": np.array([1e-3, -1e-3]),
                    "tilt_rad": np.array([np.pi / 180]), "count": np.array([2.0])}

    rng = np.random.default_rng(4)
    A = rng.normal(size=(10, 2))
    res = calibrate(ROBOT, [Reporting(A, A @ [0.1, 0.2])])
    line = res.summary().splitlines()[-1]
    assert line == ("Training errors: image RMS 3.5355 px, range RMS 1.0000 mm, "
                    "tilt RMS 1.00000 deg, count RMS 2")
    assert format_error("position_m", 2e-5) == "position 0.0200 mm"
    assert format_error("x_unknown", 0.5, "max") == "x_unknown max 0.5"


# --------------------------------------------------------------------------- validation
@pytest.fixture(scope="module")
def cross_bar():
    """Noise-free cross-bar placements (exact IK) of a perturbed PUMA: training (12
    placements) and held-out (4).  The tool-origin probe and one seating per socket
    leave the block without parameters of its own."""
    from kincal.measure.artifacts import ArtifactGeometry
    from kincal.measure.artifacts.simulate import simulate_artifact

    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(21)
    true = perturb_robot(nominal, rng)
    cross = ArtifactGeometry.cross_bar(0.3)
    train, _ = simulate_artifact(true, cross, 12, rng, model_robot=nominal, name="cross")
    held, _ = simulate_artifact(true, cross, 4, rng, model_robot=nominal, name="cross",
                                label_prefix="v")
    return nominal, true, train, held, cross, rng


def test_validate_artifact_blocks(cross_bar):
    from kincal.identify.validation import validate
    from kincal.measure.artifacts.simulate import simulate_artifact

    nominal, true, train, held, cross, rng = cross_bar
    assert len(held.parameters()) == 0
    # nothing to re-register: the true robot reproduces the held-out artifact exactly
    exact = validate(true, [held])["overall"]
    assert exact["n"] == 8 and exact["rms_distance_m"] < 1e-9
    assert exact["rms_perpendicularity_rad"] < 1e-9
    before = validate(nominal, [held])["overall"]
    res = calibrate(nominal, [train])
    after = validate(res.robot, [held], extras=res)["overall"]
    assert after["rms_distance_m"] < 0.05 * before["rms_distance_m"]
    # seated twice: socket frames (role artifact) belong to the held-out placements;
    # they are fitted on the held-out data, never looked up in the training extras
    held2, _ = simulate_artifact(true, cross, 3, rng, model_robot=nominal, name="cross",
                                 visits=2, label_prefix="w")
    assert held2.parameters().names[0] == "cross.w1.A.rz"
    v = validate(true, [held2], extras=res)
    assert v["overall"]["rms_coincidence_m"] < 1e-9 and v["overall"]["rms_distance_m"] < 1e-9
    assert set(v["extras"]["cross"]) == set(held2.parameters().names)
    # a tracker frame is no placement parameter: missing from extras is an error
    blk = make_block(true, random_configurations(nominal, 5, rng), rng, "position")
    with pytest.raises(KincalError, match="no value for 'tracker.x'"):
        validate(true, [blk], extras={"cross.x": 0.0})


def test_cross_validation_holds_out_whole_placements(cross_bar):
    from kincal.identify.validation import cross_validate

    nominal, true, train, held, cross, rng = cross_bar
    cv = cross_validate(nominal, train, folds=3)
    assert cv["split"] == "placements" and len(cv["results"]) == 3
    seen: list[str] = []
    for res in cv["results"]:
        used = res.problem.blocks[0].placements
        assert len(used) == 8
        seen += [p for p in train.placements if p not in used]
    assert sorted(seen, key=int) == list(train.placements)     # each held out once
    nominal_cv = cross_validate(nominal, train, folds=3, fixed="*")
    assert cv["rms_distance_m"] < 0.05 * nominal_cv["rms_distance_m"]
    # the protocol adds no error of its own: the true robot, nothing estimated
    exact = cross_validate(true, train, folds=3, fixed="*")
    assert exact["rms_distance_m"] < 1e-9 and exact["rms_perpendicularity_rad"] < 1e-9
    with pytest.raises(KincalError, match="folds must be between 2 and its number of "
                                          "placements"):
        cross_validate(nominal, train, folds=13)
