"""Real data: PAL TIAGo measured by Qualisys motion capture (FIGAROH's held-out protocol).

Protocol (data README): calibrate on the training session only; the motion-capture
frame (6) and the marker point in ``wrist_ft_tool_link`` (3) are estimated with the
robot parameters; RMS of the 3-D position error norm of point 1 (x1, y1, z1) on the
training file and on the validation file, the latter with the frames and parameters
from training (no refit).  FIGAROH publishes (mm, train / validation): registration
only 3.37 / 4.87; joint offsets 2.88 / 4.23; full joint placements (31) 1.64 / 3.07.

Full calibration, sixteen variants (every choice made without the validation file):

* ``least squares, point 1``: ``calibrate(robot, [train])``, the strict protocol;
* ``MAP, point 1``: the same with a Gaussian prior from manufacturing tolerances,
  fixed before looking at any result: 1 mm on every origin translation, 0.1 deg on
  every origin error rotation; encoder offsets, the mocap frame and the marker free;
  weighed against the stated 1 mm per coordinate (``noise_scale=1``: this study
  predates the estimated noise scale of :func:`calibrate`'s default);
* ``... all markers``: the four points x1..x4 are one rigid body on the hand, so
  training may use all four (the hand's orientation too); validation stays on point
  1 with the training frames, exactly as in the protocol;
* ``... + gravity compliance``: a non-geometric term (the dual-SCARA thesis): each joint deflects by
  ``k_j tau_j(q)``, ``tau`` the static gravity load computed from the URDF's
  ``<inertial>`` masses (:func:`kincal.robots.urdf.load_urdf_inertials`,
  :func:`kincal.robots.gravity.gravity_torques`) and ``k`` one compliance per joint
  [rad/(N m), m/N] (:class:`kincal.measure.joints.compliance.JointCompliance`);
* ``... + hysteresis``: each joint lags its encoder by ``h_j d_j``, ``d_j = +-1`` the
  direction the joint moved in to reach the posture, read from the session's posture
  order (:class:`kincal.measure.joints.hysteresis.JointHysteresis`): backlash held by
  friction on the side it was approached from.
  The non-geometric coefficients are estimated with the rest under the same automatic
  selection (no prior on them); validation uses the training coefficients with the
  loads and approach directions of the validation postures.

The model kincal uses for this data is the one ``kincal calibrate --select auto``
chooses from the 37 training postures alone (:mod:`kincal.identify.selection`: the
joint models and the prior scales, 10-fold cross-validation with seed 0, the lowest
cross-validated RMS among the fits that converge with every estimate within 10
tolerances): ``geometric + hysteresis, prior x3`` (CV 2.05 mm), validation 2.61 mm,
below FIGAROH's 3.07 (test_select_auto_chooses_on_training_and_validates_below_figaroh).
Every least-squares candidate is refused there (an origin moves more than 10
tolerances).  The sixteen variants below are the earlier study, kept as a record: the
MAP ones weigh a 1 mm / 0.1 deg prior on the origins against the stated 1 mm per
coordinate, as they did then.

How the hysteresis term came about, for the record: it was added after the previous
session had seen the validation numbers of the eight variants without it (dominated
by the postures outside the training ranges) and after FIGAROH's report named arm_6's
backlash.  It was kept because of its cross-validation on training (10-fold and
leave-one-out both improved by more than 0.4 mm over every model without it) and
because the play it finds has the physical sign (every resolved ``h`` is a lag:
test_hysteresis_on_tiago), not because of the validation file.

Why the geometric variants miss (diagnosed afterwards, with FIGAROH's posture groups;
nothing was chosen by it): the validation RMS is dominated by the 9 postures outside
the training joint ranges.  Two of them (arm_6 = -1.18 / arm_7 = +1.77 rad; arm_3 =
-3.14 / arm_7 = -1.58 rad) are off by 9-21 mm for every geometric model and by 12 mm
after registration only.  Inside the training ranges kincal's least squares matches
FIGAROH's full model (test_validation_by_posture_group).  The hysteresis term lowers
the "repeated" group (the same postures on another day, approached from other
directions) from 2.3 to 1.8-2.1 mm.  The gravity-compliance term finds arm_6 at 28-38
mrad/(N m) in every variant without the hysteresis (up to 29-39 mrad of deflection at
its loads of up to 1.04 N m).
"""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np
import pytest

from kincal.identify.solver import calibrate
from kincal.identify.validation import validate
from kincal.measure.instruments.position import PositionMeasurement
from kincal.measure.joints.compliance import JointCompliance
from kincal.measure.joints.terms import with_joint_model

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "tiago_mocap"

pytestmark = pytest.mark.skipif(not DATA.is_dir(),
                                reason=f"real TIAGo data not found at {DATA}")

FIGAROH_FULL = (1.64, 3.07)   # mm, train / validation, "full joint placements (31)"
#: Prior standard deviations (manufacturing tolerances, chosen a priori, not tuned):
#: 1 mm on origin translations, 0.1 deg on origin error rotations.
PRIOR = {"*.origin.x": 1e-3, "*.origin.y": 1e-3, "*.origin.z": 1e-3,
         "*.origin.r?": math.radians(0.1)}
#: Non-geometric terms: joint hysteresis (play held by friction on the side the joint
#: approached from, :class:`kincal.measure.joints.hysteresis.JointHysteresis`) and gravity
#: compliance (:class:`kincal.measure.joints.compliance.JointCompliance`).
TERMS = {"": (), " + gravity compliance": ("compliance",), " + hysteresis": ("hysteresis",),
         " + gravity compliance + hysteresis": ("compliance", "hysteresis")}
#: variant -> (markers used in training, non-geometric terms, calibrate options)
VARIANTS = {f"{est}{label}, {which}": (markers, terms, options)
            for label, terms in TERMS.items()
            for which, markers in (("point 1", 1), ("all markers", 4))
            for est, options in (("least squares", {}),
                                 ("MAP", {"prior": PRIOR, "noise_scale": 1.0}))}
#: Measured (mm, train point 1 / validation point 1) of the variants that are not below
#: FIGAROH's 3.07 on validation.
BELOW_FIGAROH = {
    "least squares, point 1": "1.591 / 4.172",
    "MAP, point 1": "2.117 / 3.530",
    "least squares, all markers": "1.842 / 3.609",
    "MAP, all markers": "1.967 / 3.387",
    "least squares + gravity compliance, point 1": "1.184 / 3.623",
    "least squares + gravity compliance, all markers": "1.367 / 3.196",
    "least squares + hysteresis, point 1": "0.832 / 3.707",
}


def tiago():
    from kincal.robots.urdf import load_urdf

    return load_urdf(DATA / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")


def session(robot, name, markers=1):
    """Marker points (x1, y1, z1 [m], ... up to ``markers``) and the joint readings."""
    with open(DATA / name, newline="") as f:
        rows = list(csv.DictReader(f))
    q = np.array([[float(r[j]) for j in robot.joint_names] for r in rows])
    y = np.array([[[float(r[f"{c}{k}"]) for c in "xyz"] for k in range(1, markers + 1)]
                  for r in rows])
    return PositionMeasurement(q, y[:, 0] if markers == 1 else y, sigma=1e-3, name="mocap")


def masses():
    """The URDF's link masses riding on the chain (gravity loads of the compliance term)."""
    from kincal.robots.urdf import load_urdf_inertials

    return load_urdf_inertials(DATA / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")


def model(robot, block, terms):
    """``block`` as calibrated: itself, or inside the joint model ``terms``
    (:func:`kincal.measure.joints.terms.with_joint_model`, what ``--joint-model`` does: hysteresis
    with directions from the session's posture order, gravity compliance with the URDF's
    masses).  Built on a whole session; cross-validation folds are subsets of it (each
    posture keeps the direction it was approached from)."""
    return with_joint_model([block], robot, terms, masses())[0] if terms else block


@pytest.fixture(scope="module")
def data():
    robot = tiago()
    return (robot, session(robot, "train_2021-11-30.csv"),
            session(robot, "validation_2021-11-26.csv"))


def point1_extras(extras):
    """Block parameters for a point-1 block: frames as given, marker 1 as ``mocap.marker``."""
    out = {k: v for k, v in extras.items() if ".marker" not in k}
    for c in "xyz":
        out[f"mocap.marker.{c}"] = extras.get(f"mocap.marker1.{c}", extras.get(f"mocap.marker.{c}"))
    return out


def rms_mm(robot, block, extras):
    """RMS [mm] of the point-1 error norm of ``block`` with frames ``extras`` (no refit)."""
    return validate(robot, [block], extras=point1_extras(extras))["overall"]["rms_position_m"] * 1e3


def test_registration_only_reproduces_figaroh(data):
    robot, train, val = data
    res = calibrate(robot, [train], free=["mocap.*"])        # no user guess anywhere
    assert res.converged and len(res.estimated) == 9
    t, v = rms_mm(res.robot, train, res.extras()), rms_mm(res.robot, val, res.extras())
    print(f"\nTIAGo registration only (9): train {t:.3f} mm, validation {v:.3f} mm "
          "(FIGAROH 3.37 / 4.87)")
    assert t == pytest.approx(3.37, abs=0.02), f"train RMS {t:.4f} mm vs FIGAROH 3.37"
    assert v == pytest.approx(4.87, abs=0.02), f"validation RMS {v:.4f} mm vs FIGAROH 4.87"


def test_joint_offsets_reproduce_figaroh(data):
    robot, train, val = data
    res = calibrate(robot, [train], free=["*.offset", "mocap.*"])
    t, v = rms_mm(res.robot, train, res.extras()), rms_mm(res.robot, val, res.extras())
    print(f"\nTIAGo joint offsets ({len(res.estimated)}): train {t:.3f} mm, validation "
          f"{v:.3f} mm (FIGAROH 14: 2.88 / 4.23)")
    assert len(res.estimated) == 14
    # the torso and arm_1 offsets cannot be told from the mocap frame, arm_7's from the marker
    dep = res.identifiability.dependent
    assert {"torso_lift_joint.offset", "arm_1_joint.offset", "arm_7_joint.offset"} <= set(dep)
    assert t == pytest.approx(2.88, abs=0.02) and v == pytest.approx(4.23, abs=0.02)


@pytest.fixture(scope="module")
def full(data):
    """Every variant fitted on training: ``{variant: (result, train mm, validation mm, s,
    terms)}``, both RMS on point 1 with the training frames (and non-geometric terms)."""
    robot, train, val = data
    train4 = session(robot, "train_2021-11-30.csv", markers=4)
    out = {}
    for name, (markers, terms, options) in VARIANTS.items():
        start = time.perf_counter()
        res = calibrate(robot, [model(robot, train if markers == 1 else train4, terms)],
                        **options)
        took = time.perf_counter() - start
        out[name] = (res, rms_mm(res.robot, model(robot, train, terms), res.extras()),
                     rms_mm(res.robot, model(robot, val, terms), res.extras()), took, terms)
    reg = calibrate(robot, [train], free=["mocap.*"])
    out["registration only"] = (reg, rms_mm(reg.robot, train, reg.extras()),
                                rms_mm(reg.robot, val, reg.extras()), 0.0, ())
    lines = [f"TIAGo full automatic calibration, point-1 RMS [mm] (FIGAROH full 31: "
             f"{FIGAROH_FULL[0]:.2f} / {FIGAROH_FULL[1]:.2f}):"]
    for name, (res, t, v, s, _) in out.items():
        tag = ""
        lines.append(f"  {name:62s} {len(res.estimated):2d} params  train {t:.3f}  "
                     f"validation {v:.3f}   ({res.iterations} iterations, {s:.2f} s){tag}")
    print("\n" + "\n".join(lines))
    return out


def test_full_calibration_is_well_posed(full):
    """The URDF origins (fixed nominal rotation + error rotations) are well conditioned:
    33 identifiable parameters, scaled condition number ~250, ~10 LM iterations."""
    res, t, v, _, _ = full["least squares, point 1"]
    assert res.converged, res.message
    assert len(res.estimated) == 33 and len(res.names) == 100
    assert res.identifiability.cond_scaled < 300
    assert res.iterations <= 20
    assert np.all(np.isfinite(res.std))
    # the torso slide's direction relative to the arm is identified (as arm_1's origin
    # tilt); the torso's own origin and offset are absorbed by the mocap frame
    assert {"arm_1_joint.origin.rx", "arm_1_joint.origin.ry"} <= set(res.estimated)
    assert not any(n.startswith("torso_lift_joint.") for n in res.estimated)
    assert res.identifiability.dependent["torso_lift_joint.offset"] == ["mocap.z"]


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_full_calibration_variants(full, variant):
    res, t, v, _, terms = full[variant]
    _, t0, v0, _, _ = full["registration only"]
    assert res.converged, res.message
    assert np.all(np.isfinite(res.std))
    assert t < 0.65 * t0 and v < v0, (t, v, t0, v0)   # better on both days
    if "MAP" in variant:
        assert set(res.prior) == {n for n in res.estimated if ".origin." in n}
        # the prior does not change which parameters are estimated
        assert res.estimated == full[variant.replace("MAP", "least squares")][0].estimated
    k = [n for n in res.names if ".k[" in n]
    h = [n for n in res.names if ".h[" in n]
    assert bool(k) == ("compliance" in terms) and bool(h) == ("hysteresis" in terms)
    # the same geometric selection as without the non-geometric terms ...
    plain = full[variant.replace(" + gravity compliance", "").replace(" + hysteresis", "")][0]
    assert [n for n in res.estimated if ".k[" not in n and ".h[" not in n] == plain.estimated
    # ... plus the compliances of the loaded arm joints and every joint's hysteresis
    assert [n for n in res.estimated if ".k[" in n] == k[2:]
    assert [n for n in res.estimated if ".h[" in n] == h


def test_gravity_compliance_on_tiago(data, full):
    """Which compliances the data can see, and arm_6's value in every variant without
    the hysteresis term (with it, arm_6's play is shared between the two terms).

    arm_1 turns about the vertical: no gravity load, its compliance is unobservable.  The
    torso slide always carries the same 18.9 kg, so its deflection is a constant shift,
    absorbed by the mocap frame's z.  arm_6 comes out at 28-38 mrad/(N m) whatever the
    estimator and markers (2-3 standard errors from zero with point 1 alone, 15-19 with all
    four markers): up to 29-39 mrad of deflection at its loads of up to 1.04 N m, the
    gravity-loaded arm_6 backlash (~40 mrad) that FIGAROH's report names.  arm_7 carries
    < 0.08 N m: its compliance is estimated but within two standard errors of zero."""
    lines = ["TIAGo gravity compliance k +- std [mrad/(N m)], arm_2 .. arm_7:"]
    for name, (res, _, _, _, terms) in full.items():
        if "compliance" not in terms:
            continue
        rep = res.identifiability
        assert rep.unobservable == ["mocap.k[arm_1_joint]"]
        assert rep.dependent["mocap.k[torso_lift_joint]"] == ["mocap.z"]
        k = {i: (res.params[f"mocap.k[arm_{i}_joint]"],
                 res.std[res.names.index(f"mocap.k[arm_{i}_joint]")]) for i in range(2, 8)}
        if "hysteresis" not in terms:     # with the hysteresis, arm_6's play is shared between both
            assert 0.025 < k[6][0] < 0.040, (name, k[6])
            assert k[6][0] > (10 if "all markers" in name else 2) * k[6][1], (name, k[6])
            assert abs(k[7][0]) < 2 * k[7][1], (name, k[7])
        lines.append(f"  {name:47s} " + ", ".join(f"{v * 1e3:.1f} +- {s * 1e3:.1f}"
                                                  for v, s in k.values()))
    print("\n" + "\n".join(lines))
    robot, train, _ = data
    tau = JointCompliance.gravity(train, robot, masses()).torques
    assert 0.9 < np.abs(tau[:, 6]).max() < 1.1                      # N m on arm_6
    np.testing.assert_allclose(tau[:, 0], -18.9 * 9.81, rtol=2e-3)  # N on the torso


def test_map_is_the_prior_augmented_least_squares_optimum(data, full):
    """``calibrate(prior=...)`` against scipy's least_squares on the same residuals with
    the rows ``(theta_j - nominal_j) / s_j`` appended, over the same estimated set."""
    from scipy.optimize import least_squares

    from kincal.errors import KincalError

    robot, train, _ = data
    res = full["MAP, point 1"][0]
    prob, theta0 = res.problem, res.theta0
    est = [prob.names.index(n) for n in res.estimated]
    pri = [k for k, i in enumerate(est) if prob.names[i] in res.prior]
    inv = np.array([1.0 / res.prior[prob.names[est[k]]] for k in pri])

    def fun(x):
        theta = theta0.copy()
        theta[est] = x
        return np.concatenate([prob.residuals(theta), (x[pri] - theta0[est][pri]) * inv])

    ref = least_squares(fun, theta0[est], x_scale="jac", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, method="trf")
    units = np.array([1e3 if prob.units[i] == "m" else math.degrees(1.0) for i in est])
    # within the solver's stopping rule: 1e-3 standard errors of the minimum (tol_std)
    assert np.abs((res.theta[est] - ref.x) / res.std[est]).max() <= 1e-3
    assert res.cost == pytest.approx(0.5 * np.sum(ref.fun**2), rel=1e-9)
    # a very wide prior is least squares; a very narrow one holds the nominal origins
    wide = calibrate(robot, [train], prior={"*.origin.*": 1e3}, noise_scale=1.0)
    ls = full["least squares, point 1"][0]
    assert np.abs((wide.theta - ls.theta)[est] * units).max() < 1e-3
    tight = calibrate(robot, [train], prior={"*.origin.*": 1e-9}, noise_scale=1.0)
    i = [k for k, n in enumerate(tight.names) if ".origin." in n]
    assert np.abs(tight.theta[i] - tight.theta0[i]).max() < 1e-8
    with pytest.raises(KincalError, match="positive and finite"):
        calibrate(robot, [train], prior={"*.origin.x": 0.0})
    with pytest.raises(KincalError, match="no parameter matches"):
        calibrate(robot, [train], prior={"*.origin.yaw": 1e-3})


def posture_groups(train, val, tol=0.01, margin=0.05):
    """FIGAROH's groups of validation postures: repeated (every joint within ``tol`` of a
    training posture), out of range (some joint beyond the training range by more than
    ``margin``), new (the rest)."""
    nearest = np.array([np.min(np.max(np.abs(train.q - x), axis=1)) for x in val.q])
    repeated = nearest < tol
    outside = np.any((val.q < train.q.min(0) - margin) | (val.q > train.q.max(0) + margin), 1)
    return {"repeated": repeated, "new": ~repeated & ~outside,
            "out of range": outside & ~repeated}


def test_validation_by_posture_group(data, full):
    """FIGAROH's full model (31), validation by group: repeated 2.34, new 2.84, out of
    range 5.31 mm (37 / 16 / 9 postures).  kincal's least squares matches it inside the
    training ranges; the difference is in the extrapolated postures.  (A diagnosis on
    the validation file; no variant or setting is chosen from it.)"""
    robot, train, val = data
    groups = posture_groups(train, val)
    assert [int(m.sum()) for m in groups.values()] == [37, 16, 9]
    figaroh = {"repeated": 2.34, "new": 2.84, "out of range": 5.31}
    lines = ["TIAGo validation by posture group, point-1 RMS [mm] "
             f"(FIGAROH full 31: {', '.join(f'{k} {v:.2f}' for k, v in figaroh.items())}):"]
    got = {}
    for name in [*VARIANTS, "registration only"]:
        res, terms = full[name][0], full[name][4]
        block = model(robot, val, terms)
        extras = point1_extras(res.extras())
        e = block.errors(res.robot, np.array([extras[n] for n in block.parameters().names]))
        got[name] = {k: float(np.sqrt(np.mean(e["position_m"][m] ** 2))) * 1e3
                     for k, m in groups.items()}
        lines.append(f"  {name:62s} " + ", ".join(f"{k} {v:.2f}" for k, v in got[name].items()))
    print("\n" + "\n".join(lines))
    # registration only reproduces FIGAROH's groups too: 3.93 / 5.12 / 7.34
    reg = got["registration only"]
    for k, v in zip(groups, (3.93, 5.12, 7.34), strict=True):
        assert reg[k] == pytest.approx(v, abs=0.02), (k, reg[k])
    ls = got["least squares, point 1"]
    assert ls["repeated"] == pytest.approx(figaroh["repeated"], abs=0.1)
    assert ls["new"] == pytest.approx(figaroh["new"], abs=0.1)
    assert ls["out of range"] > figaroh["out of range"] + 2.0


@pytest.fixture(scope="module")
def auto(data):
    """``--select auto`` on the 37 training postures (point 1): every joint model and
    prior scale, 10-fold cross-validation with seed 0, the default tolerances."""
    from kincal.identify.selection import select_model
    from kincal.measure.base import stack
    from kincal.workflow.flow import tolerances_of

    robot, train, _ = data
    tol = tolerances_of(robot, stack(robot, [train])[0])
    return select_model(robot, [train], tol.sigma, masses=masses(), folds=10), tol


def test_select_auto_chooses_on_training_and_validates_below_figaroh(data, auto):
    """kincal's model for this data is the one ``--select auto`` picks from the training
    file alone; its validation RMS on the other day, against FIGAROH's 3.07 mm."""
    robot, train, val = data
    sel, tol = auto
    print("\nTIAGo --select auto, 10-fold CV RMS on the 37 training postures [mm]: "
          + ", ".join(f"{c.label} {r * 1e3:.3f}{'' if ok else ' (not eligible)'}"
                      for c, r, ok in zip(sel.candidates, sel.rms, sel.trusted, strict=True)))
    choice = sel.choice
    assert choice is not None and choice.terms == ("hysteresis",) and choice.scale == 3.0
    # least squares is never eligible here: some origin moves beyond 10 tolerances
    assert not any(ok for c, ok in zip(sel.candidates, sel.trusted, strict=True)
                   if c.scale is None)
    res = calibrate(robot, [model(robot, train, choice.terms)],
                    prior={n: s * choice.scale for n, s in tol.sigma.items()})
    t = rms_mm(res.robot, model(robot, train, choice.terms), res.extras())
    v = rms_mm(res.robot, model(robot, val, choice.terms), res.extras())
    print(f"TIAGo --select auto's choice ({choice.label}, {len(res.estimated)} parameters): "
          f"train {t:.3f} mm, validation {v:.3f} mm; FIGAROH full 31: "
          f"{FIGAROH_FULL[0]:.2f} / {FIGAROH_FULL[1]:.2f} mm")
    assert res.converged and v < FIGAROH_FULL[1]


def test_result_table(full):
    """Every variant next to FIGAROH's published numbers (train / validation [mm])."""
    head = f"  {'TIAGo, point-1 RMS [mm]':76s} {'train':>6s} {'valid.':>6s}"
    lines = [head]
    for name, (t, v) in {"FIGAROH registration only (9)": (3.37, 4.87),
                         "FIGAROH joint offsets (14)": (2.88, 4.23),
                         "FIGAROH full joint placements (31)": FIGAROH_FULL}.items():
        lines.append(f"  {name:76s} {t:6.2f} {v:6.2f}")
    for name in ["registration only", *VARIANTS]:
        res, t, v, _, _ = full[name]
        label = f"kincal {name} ({len(res.estimated)})"
        lines.append(f"  {label:76s} {t:6.3f} {v:6.3f}")
    print("\n" + "\n".join(lines))
    assert set(full) == {"registration only", *VARIANTS}


def test_hysteresis_on_tiago(full):
    """The play the data sees, every variant with the hysteresis term.

    Every play more than three standard errors from zero is a lag (``h < 0``: the link
    stops short of its motor), the sign backlash must have; nothing in the model imposes
    it.  arm_6, whose ~40 mrad backlash FIGAROH's report names, lags in every variant
    (3-13 mrad); with all four markers it is 5.8-11 mrad at 9-14 standard errors, and
    arm_5 (the joint with encoder trouble in FIGAROH's report) 5.4-7.8 mrad at 4-6."""
    lines = ["TIAGo joint hysteresis h +- std [mrad] (torso [mm]), torso, arm_1 .. arm_7:"]
    for name, (res, _, _, _, terms) in full.items():
        if "hysteresis" not in terms:
            continue
        h = {j: (res.params[f"mocap.h[{j}]"], res.std[res.names.index(f"mocap.h[{j}]")])
             for j in res.robot.joint_names}
        lines.append(f"  {name:62s} " + ", ".join(f"{v * 1e3:.1f} +- {s * 1e3:.1f}"
                                                  for v, s in h.values()))
        for j, (v, s) in h.items():
            assert v < 3 * s, (name, j, v, s)        # no resolved play leads its motor
        v6, s6 = h["arm_6_joint"]
        assert v6 < 0, (name, v6)
        if "all markers" in name:
            assert -0.012 < v6 < -0.005 and v6 < -8 * s6, (name, v6, s6)
            v5, s5 = h["arm_5_joint"]
            assert -0.009 < v5 < -0.004 and v5 < -3 * s5, (name, v5, s5)
    print("\n" + "\n".join(lines))


def _reason(name):
    return (f"measured {BELOW_FIGAROH[name]} mm (train / validation) vs FIGAROH 1.64 / "
            "3.07: a variant cross-validation does not pick; the validation RMS is "
            "dominated by postures outside the training joint ranges (module docstring)")


@pytest.mark.parametrize("variant", [
    pytest.param(name, marks=pytest.mark.xfail(strict=True, reason=_reason(name)))
    if name in BELOW_FIGAROH else name for name in VARIANTS])
def test_validation_below_figaroh(full, variant):
    res, t, v, _, _ = full[variant]
    print(f"\nTIAGo {variant} ({len(res.estimated)}): train {t:.3f} mm, validation {v:.3f} mm; "
          f"FIGAROH full 31: {FIGAROH_FULL[0]:.2f} / {FIGAROH_FULL[1]:.2f} mm")
    assert v < FIGAROH_FULL[1], f"{variant}: validation {v:.3f} mm >= FIGAROH's 3.07"
