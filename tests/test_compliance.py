"""Joint compliance wrapper: Jacobians vs central differences, exact recovery of known
compliances from noise-free simulated data, identifiability and errors."""

from __future__ import annotations

import numpy as np
import pytest
from test_models import central_differences, stanford

from kincal.errors import KincalError
from kincal.identify.solver import calibrate
from kincal.measure.base import MeasurementModel, ParamSpec, stack
from kincal.measure.instruments.pose import PoseMeasurement
from kincal.measure.instruments.position import PositionMeasurement, simulate_positions
from kincal.measure.joints.compliance import JointCompliance
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.chain import ChainBuilder
from kincal.robots.files import load_serial_robot
from kincal.robots.gravity import PointMass, gravity_torques

INSTRUMENT = [1.4, -0.6, 0.3, 2.1, -0.3, 0.2]          # x y z rz ry rx
MARKERS = np.array([[0.05, 0.0, 0.1], [-0.04, 0.06, 0.08], [0.0, -0.05, 0.12]])
#: Synthetic PUMA 560 masses [kg] and centres [m] (frame just after each joint's
#: rotation).  Joint 1 turns about the vertical (no gravity load); joint 6's mass sits on
#: its axis (no load either).
PUMA_MASSES = [PointMass(0, 13.0, (0.0, 0.0, 0.3)), PointMass(1, 17.4, (0.2, 0.0, 0.1)),
               PointMass(2, 4.8, (0.02, 0.01, 0.2)), PointMass(3, 0.8, (0.0, 0.05, 0.4)),
               PointMass(4, 0.34, (0.0, 0.03, 0.0)), PointMass(5, 0.09, (0.0, 0.0, 0.03))]


def flipped():
    """A 3-joint chain whose joints turn about -z, -y and slide along -x (``s = -1``)."""
    b = ChainBuilder("flipped")
    b.frame("base", [0.1, 0.0, 0.3, 0.0, 0.0, 0.1])
    j = b.joint("a", "revolute", -3, 3)
    b.transform("Rz", "a.offset", 0.1, role="offset", joint=j, scale=-1.0)
    b.transform("Tx", "l1", 0.4)
    j = b.joint("b", "revolute", -3, 3)
    b.transform("Ry", "b.offset", -0.2, role="offset", joint=j, scale=-1.0)
    b.transform("Tz", "l2", 0.3)
    j = b.joint("c", "prismatic", 0.0, 0.5)
    b.transform("Tx", "c.offset", 0.0, role="offset", joint=j, scale=-1.0)
    b.transform("Rx", "t1", 0.3, role="angle")
    b.frame("tool", [0.05, 0.02, 0.1, 0.0, 0.0, 0.0])
    return b.build()


def _masses(robot):
    """Loads for any test robot: 1-2 kg somewhere off each joint's axis."""
    return [PointMass(j, 1.0 + 0.2 * j, (0.05, -0.03 * j, 0.1)) for j in range(robot.n)]


@pytest.mark.parametrize("which", ["puma", "stanford", "flipped"])
@pytest.mark.parametrize("kind", ["position", "pose"])
def test_jacobian_matches_central_differences(which, kind):
    robot = {"puma": lambda: load_serial_robot("puma560"), "stanford": stanford,
             "flipped": flipped}[which]()
    rng = np.random.default_rng(1)
    q = random_configurations(robot, 9, rng)
    tau = gravity_torques(robot, q, PUMA_MASSES if which == "puma" else _masses(robot),
                          g=(0.3, -0.2, -9.81))
    if kind == "position":
        sim = simulate_positions(robot, q, rng, 1e-3, INSTRUMENT, MARKERS[:2])
        inner = PositionMeasurement(q, sim.positions, rng.uniform(0.5e-3, 2e-3, (9, 2)),
                                    "tracker", markers=2)
    else:
        inner = PoseMeasurement(q, np.repeat(np.eye(4)[None], 9, 0), 1e-3, 2e-3, "tracker")
    block = JointCompliance(inner, robot, tau)
    prob, theta = stack(robot, [block])
    theta = theta + 1e-3 * rng.standard_normal(theta.size)
    k_idx = [prob.index(f"tracker.k[{j}]") for j in robot.joint_names]
    theta[k_idx] = rng.uniform(-0.02, 0.05, robot.n) / np.maximum(np.abs(tau).max(0), 1.0)
    r, J = prob.residuals_and_jacobian(theta)
    Jn = central_differences(prob, theta)
    scale = np.maximum(np.abs(Jn).max(0), 1e-3 * np.abs(Jn).max())
    assert np.max(np.abs(J - Jn) / scale) < 1e-6
    # the k columns are dr/dq_j * tau_j: not trivially zero here
    assert np.all(np.abs(J[:, k_idx]).max(0) > 0)
    # the chunked pieces are the same rows
    robot_t, (extra,) = prob.split(theta)
    pieces = list(block.evaluate_chunks(robot_t, extra, rows=12))
    r2 = np.concatenate([p[1] for p in pieces])
    Je2 = np.concatenate([p[3] for p in pieces])
    _, _, Je = block.evaluate(robot_t, extra)
    np.testing.assert_allclose(r2, r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Je2, Je, rtol=0, atol=1e-9 * np.abs(Je).max())


def test_effective_configurations_and_inner_block_untouched():
    robot = stanford()
    rng = np.random.default_rng(2)
    q = random_configurations(robot, 7, rng)
    sim = simulate_positions(robot, q, rng, 0.0, INSTRUMENT, MARKERS)
    inner = PositionMeasurement(q, sim.positions, 1e-5, "tracker", markers=3)
    q_before = inner.q.copy()
    tau = gravity_torques(robot, q, _masses(robot))
    block = JointCompliance(inner, robot, lambda x: gravity_torques(robot, x, _masses(robot)),
                            joints=["q2", "q3"])
    np.testing.assert_array_equal(block.torques, tau)
    assert block.parameters().names[-2:] == ("tracker.k[q2]", "tracker.k[q3]")
    assert block.parameters().units[-2:] == ("rad/(N m)", "m/N")
    assert block.parameters().roles[-1] == "compliance"
    extra = np.concatenate([inner.initial_guess(robot), [0.01, 2e-4]])
    q_eff = block.effective_q(robot, extra)
    np.testing.assert_allclose(q_eff[:, 1], q[:, 1] + 0.01 * tau[:, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(q_eff[:, 2], q[:, 2] + 2e-4 * tau[:, 2], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(q_eff[:, [0, 3, 4, 5]], q[:, [0, 3, 4, 5]])
    # the wrapper's residuals and errors are the inner model's at q_eff
    shifted = PositionMeasurement(q_eff, sim.positions, 1e-5, "tracker", markers=3)
    r, Jr, Je = block.evaluate(robot, extra)
    r_ref, Jr_ref, Je_ref = shifted.evaluate(robot, extra[:-2])
    np.testing.assert_array_equal(r, r_ref)
    np.testing.assert_array_equal(Jr, Jr_ref)
    np.testing.assert_array_equal(Je[:, :-2], Je_ref)
    e = block.errors(robot, extra)["position_m"]
    np.testing.assert_array_equal(e, shifted.errors(robot, extra[:-2])["position_m"])
    # ... and the inner block itself never moved
    assert inner.q is not q_eff
    np.testing.assert_array_equal(inner.q, q_before)
    np.testing.assert_array_equal(block.q, q_before)
    # zero compliance is the inner model
    extra0 = np.concatenate([extra[:-2], [0.0, 0.0]])
    np.testing.assert_array_equal(block.evaluate(robot, extra0, jacobian=False)[0],
                                  inner.evaluate(robot, extra0[:-2], jacobian=False)[0])
    # subsets keep rows, loads and joints
    sub = block.subset([1, 4])
    np.testing.assert_array_equal(sub.torques, tau[[1, 4]])
    np.testing.assert_array_equal(sub.errors(robot, extra)["position_m"], e[[1, 4]])
    assert sub.joints == ("q2", "q3") and sub.N == 2


def _simulate(robot_true, robot_nominal, q, k, masses, rng):
    """Noise-free positions of the true robot at ``q + k tau`` (loads from the nominal
    robot, as the model computes them), recorded with the readings ``q``."""
    tau = gravity_torques(robot_nominal, q, masses)
    sim = simulate_positions(robot_true, q + k * tau, rng, 0.0, INSTRUMENT, MARKERS)
    return PositionMeasurement(q, sim.positions, 1e-5, "tracker", markers=3), tau


#: Compliances of the simulated PUMA [rad/(N m)]; joints 1 and 6 carry no load.
K_TRUE = np.array([0.0, 2e-3, 5e-3, 3e-2, 8e-2, 0.0])


def perturbed_puma(nominal, rng):
    """A "true" PUMA 560: errors on the chain's parameters, except d[3]: with nominally
    parallel axes 2-3 it is held as dependent on d[2], which absorbs it only while the
    axes stay parallel."""
    return perturb_robot(nominal, rng, names=[n for n in nominal.param_names if n != "d[3]"
                                              and not n.startswith(("base.", "tool."))])


def test_noise_free_recovery_of_known_compliances():
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(7)
    true = perturbed_puma(nominal, rng)
    k_true = K_TRUE
    q = random_configurations(nominal, 60, rng)
    inner, _ = _simulate(true, nominal, q, k_true, PUMA_MASSES, rng)
    block = JointCompliance.gravity(inner, nominal, PUMA_MASSES, joints=["q2", "q3", "q4",
                                                                         "q5"])
    res = calibrate(nominal, [block], tol_step=1e-14)
    assert res.converged, res.message
    k = np.array([res.params[f"tracker.k[q{j}]"] for j in (2, 3, 4, 5)])
    assert set(res.estimated) >= {f"tracker.k[q{j}]" for j in (2, 3, 4, 5)}
    np.testing.assert_allclose(k, k_true[1:5], rtol=0, atol=1e-12)      # rad/(N m)
    assert res.rms()["rms_position_m"] < 1e-12
    # the geometric model alone cannot fit the deflections
    plain = calibrate(nominal, [inner])
    assert plain.rms()["rms_position_m"] > 1e-5


def test_unloaded_joints_are_unobservable_by_name():
    """Joint 1 turns about gravity and joint 6 carries its mass on its axis: no load, so
    their compliances do not change any measurement."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(8)
    q = random_configurations(nominal, 40, rng)
    inner, tau = _simulate(nominal, nominal, q, np.zeros(6), PUMA_MASSES, rng)
    assert np.abs(tau[:, [0, 5]]).max() < 1e-12 and np.abs(tau[:, 1:5]).min(0).max() > 0
    res = calibrate(nominal, [JointCompliance.gravity(inner, nominal, PUMA_MASSES)])
    rep = res.identifiability
    assert {"tracker.k[q1]", "tracker.k[q6]"} <= set(rep.unobservable)
    assert {f"tracker.k[q{j}]" for j in (2, 3, 4, 5)} <= set(res.estimated)
    text = " ".join(rep.describe())
    assert "tracker.k[q1] does not affect these measurements" in text
    assert res.params["tracker.k[q1]"] == 0.0 and res.std[res.names.index("tracker.k[q1]")] == 0


class _Pairs(MeasurementModel):
    """A toy block whose residual i depends on rows i and i + 1 (like a distance)."""

    def __init__(self, q):
        self.name = "pairs"
        self.q = np.asarray(q, dtype=float)

    def parameters(self):
        return ParamSpec.empty()

    def initial_guess(self, robot):
        return np.zeros(0)

    def evaluate(self, robot, extra, jacobian=True):
        p = robot.fk(self.q)[:, :3, 3]
        r = np.linalg.norm(p[1:] - p[:-1], axis=1)
        if not jacobian:
            return r, None, None
        return r, np.zeros((r.size, robot.num_params)), np.zeros((r.size, 0))

    def residual_owner(self):
        return np.arange(self.q.shape[0] - 1)


def test_clear_errors():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(4)
    q = random_configurations(robot, 12, rng)
    inner = simulate_positions(robot, q, rng, 0.0, INSTRUMENT)
    tau = gravity_torques(robot, q, PUMA_MASSES)
    with pytest.raises(KincalError, match=r"loads must be \(N, n\) = \(12, 6\)"):
        JointCompliance(inner, robot, tau[:, :5])
    with pytest.raises(KincalError, match="'q7' is not a joint of robot"):
        JointCompliance(inner, robot, tau, joints=["q7"])
    with pytest.raises(KincalError, match="listed twice"):
        JointCompliance(inner, robot, tau, joints=["q2", "q2"])
    bad = tau.copy()
    bad[3, 1] = np.nan
    with pytest.raises(KincalError, match="row 3 is not finite"):
        JointCompliance(inner, robot, bad)
    # a joint whose elementary transform has no parameter: dr/dq cannot be read
    b = ChainBuilder("bare")
    j = b.joint("free", "revolute")
    b.transform("Rz", None, 0.0, joint=j)
    b.transform("Tx", "l", 0.5)
    bare = b.build()
    qb = np.linspace(-1, 1, 5)[:, None]
    blk = JointCompliance(PositionMeasurement(qb, np.zeros((5, 3)), name="t"), bare,
                          np.ones((5, 1)))
    prob, theta = stack(bare, [blk])
    with pytest.raises(KincalError, match="joint 'free' has no offset parameter"):
        prob.residuals_and_jacobian(theta)
    # residuals that join two configurations
    pairs = JointCompliance(_Pairs(q), robot, tau)
    with pytest.raises(KincalError, match="depend on configurations other than"):
        pairs.evaluate(robot, np.zeros(6))
    # the robot evaluated must be the one the model was built for
    with pytest.raises(KincalError, match="model was built for"):
        JointCompliance(inner, robot, tau).evaluate(flipped(), np.zeros(15))
