"""A calibration that cannot be trusted says so: tolerances, the verdict, exit status 1.

Truth: a simulated PUMA 560 whose fifth joint moves by only 1 deg in the data.  The
parameters tied to that joint pass the rank test but are set by the noise: plain least
squares moves them by tens of tolerances (or does not converge).  The same robot
measured over its whole joint ranges calibrates to a trusted result.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import run

from kincal.errors import KincalError
from kincal.identify.checks import judge
from kincal.identify.solver import calibrate
from kincal.identify.tolerances import (
    DEFAULT_TOLERANCES,
    describe_defaults,
    parse_tolerance_entries,
    resolve_tolerances,
)
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.registry import write_measurements
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot

NOISE = 1e-5


def narrow_joint_data(joint: int = 4, span_deg: float = 1.0, n: int = 40, seed: int = 0,
                      noise: float = NOISE):
    """Nominal PUMA, a perturbed truth and tracker data in which ``joint`` (0-based)
    moves over ``span_deg`` only; every other joint over its range."""
    nominal = load_serial_robot("puma560")
    rng = np.random.default_rng(seed)
    truth = perturb_robot(nominal, rng, length_std=5e-4, angle_std=math.radians(0.05),
                          offset_std=math.radians(0.1))
    q = random_configurations(nominal, n, rng)
    q[:, joint] = q[0, joint] + np.radians(rng.uniform(-span_deg / 2, span_deg / 2, n))
    return nominal, truth, simulate_positions(truth, q, rng, noise_std=NOISE, sigma=NOISE)


def test_default_tolerances_by_role_and_unit():
    robot = load_serial_robot("puma560")
    t = resolve_tolerances(robot.param_names, robot.param_units, robot.param_roles)
    assert t.sigma["a[2]"] == 1e-3 and t.sigma["d[4]"] == 1e-3
    assert t.sigma["alpha[1]"] == pytest.approx(math.radians(0.1))
    assert t.sigma["theta_offset[3]"] == pytest.approx(math.radians(0.5))
    assert "base.x" not in t.sigma and "tool.rz" not in t.sigma      # the user's frames
    assert t.source["a[2]"] == "default length" and t.use_prior and t.scale == 1.0
    assert DEFAULT_TOLERANCES["offset"]["m"] == 1e-3                  # prismatic zero
    assert describe_defaults() == "length 1 mm, angle 0.1 deg, offset 0.5 deg (prismatic 1 mm)"


def test_robot_file_and_prior_override_later_wins():
    robot = load_serial_robot("puma560")
    args = (robot.param_names, robot.param_units, robot.param_roles)
    t = resolve_tolerances(*args, {"length": "0.5mm", "d[4]": "2mm", "role:offset": "none"},
                           "a[*]=0.2mm,scale=3", robot_source="arm.yaml")
    assert t.sigma["d[2]"] == pytest.approx(5e-4) and t.source["d[2]"] == "robot file"
    assert t.sigma["d[4]"] == pytest.approx(2e-3)
    assert t.sigma["a[2]"] == pytest.approx(2e-4) and t.source["a[2]"] == "--prior"
    assert "theta_offset[1]" not in t.sigma
    assert t.scale == 3 and t.prior()["a[2]"] == pytest.approx(6e-4)
    none = resolve_tolerances(*args, None, "none")
    assert not none.use_prior and none.prior() == {} and none.sigma["a[2]"] == 1e-3
    assert parse_tolerance_entries("default").entries == ()


@pytest.mark.parametrize("text,message", [
    ("a[*]=1", "'a[*]=1' needs a unit (e.g. a[*]=1mm or a[*]=1deg)"),
    ("a[*]=0.1deg", "'a[*]' matches no angle parameter"),
    ("a[*]=1furlong", "unknown unit 'furlong'"),
    ("a[*]=0mm", "must be positive"),
    ("a[*]", "is not PATTERN=SIGMA with a unit"),
    ("b[*]=1mm", "no parameter matches 'b[*]'"),
    ("scale=-1", "the scale must be positive"),
    ("scale=big", "the scale is a plain number"),
    ("role:wheel=1mm", "no parameter has role 'wheel'"),
])
def test_bad_tolerance_entries_are_one_line(text, message):
    robot = load_serial_robot("puma560")
    with pytest.raises(KincalError) as err:
        resolve_tolerances(robot.param_names, robot.param_units, robot.param_roles, None, text)
    assert message in str(err.value) and str(err.value).startswith("option --prior: ")


def test_a_joint_moved_by_one_degree_gives_an_untrusted_least_squares_fit():
    nominal, _, data = narrow_joint_data()
    res = calibrate(nominal, [data])
    p = res.problem
    v = judge(res, resolve_tolerances(p.names, p.units, p.roles).sigma)
    assert not v.trusted
    names = {x.name for x in v.implausible}
    # the parameters of the wrist joints next to the one that barely moves
    assert names & {"alpha[4]", "alpha[5]", "theta_offset[5]", "theta_offset[4]"}, v.line()
    for x in v.implausible:
        assert abs(x.change) > 10 * x.tolerance
    line = v.line()
    assert line.startswith("calibration not trusted: ") and "\n" not in line
    assert "x its tolerance" in line
    # the same robot measured over the whole ranges is trusted
    rng = np.random.default_rng(3)
    q = random_configurations(nominal, 40, rng)
    good = calibrate(nominal, [simulate_positions(narrow_joint_data()[1], q, rng, NOISE)])
    assert judge(good, resolve_tolerances(p.names, p.units, p.roles).sigma).trusted


@pytest.fixture(scope="module")
def narrow_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("narrow")
    _, _, data = narrow_joint_data()
    path = d / "narrow.csv"
    write_measurements("position", [data], path, {"length": "mm", "angle": "deg"})
    return path


def test_untrusted_calibration_exits_1_and_writes_no_robot(narrow_file, capsys, tmp_path):
    out, j, rep = tmp_path / "cal.yaml", tmp_path / "res.json", tmp_path / "rep.html"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", narrow_file, "-o", out,
                            "--json", j, "--report", rep, "--prior", "none")
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: calibration not trusted: ")
    assert "x its tolerance" in lines[0] and "--force writes it" in lines[0]
    assert not out.exists()
    doc = json.loads(j.read_text())
    assert doc["verdict"]["trusted"] is False and doc["not_written"] == {"robot": str(out)}
    assert "robot" not in doc["outputs"] and doc["verdict"]["implausible"]
    assert "calibration not trusted" in rep.read_text()
    assert "Estimated parameters" in stdout           # the tables are still printed
    # --force writes the robot, and the exit status still says the check failed
    code, _, err = run(capsys, "calibrate", "puma560", "--data", narrow_file, "-o", out,
                       "--prior", "none", "--force")
    assert code == 1 and out.exists() and "written anyway (--force)" in err


def test_robot_file_tolerances_section(tmp_path):
    from kincal.errors import RobotFileError
    from kincal.robots.files import robot_yaml_text

    robot = load_serial_robot("puma560")
    text = robot_yaml_text(robot).replace("units:", "tolerances: {length: 0.2mm, 'd[4]': "
                                          "none}\nunits:", 1)
    f = tmp_path / "arm.yaml"
    f.write_text(text)
    arm = load_serial_robot(f)
    assert arm.meta["tolerances"] == {"length": "0.2mm", "d[4]": "none"}
    assert "tolerances:" in robot_yaml_text(arm)
    t = resolve_tolerances(arm.param_names, arm.param_units, arm.param_roles,
                           arm.meta["tolerances"])
    assert t.sigma["a[2]"] == pytest.approx(2e-4) and "d[4]" not in t.sigma
    f.write_text(text.replace("0.2mm", "0.2"))
    with pytest.raises(RobotFileError, match="field 'tolerances.length' needs a unit"):
        load_serial_robot(f)


def test_the_default_prior_holds_the_weak_parameters_and_names_the_joint():
    """The same data with the default prior (tolerances, noise scale estimated): the fit
    converges, every estimate is plausible, the three parameters of the wrist that the
    1-deg joint leaves weak are held by the prior, each named with joint q5, and the
    truth is within three posterior standard errors of each."""
    from kincal.identify.weak import weak_parameters
    from kincal.measure.base import stack

    nominal, truth, data = narrow_joint_data()
    prob, _ = stack(nominal, [data])
    tol = resolve_tolerances(prob.names, prob.units, prob.roles)
    res = calibrate(nominal, [data], prior=tol.prior())
    assert res.converged and judge(res, tol.sigma).trusted
    assert res.noise_scale_estimated and 0.7 < res.sigma0 < 1.3       # the noise is as stated
    assert set(res.held_by_prior) == {"theta_offset[4]", "alpha[4]", "alpha[5]"}
    weak = weak_parameters(res)
    assert [w.name for w in weak] == res.held_by_prior
    true = dict(zip(truth.param_names, truth.param_values, strict=True))
    for w in weak:
        assert w.joint == "q5" and w.data_std > 10 * w.prior_std
        assert w.with_joint < w.data_std / 50          # spreading q5 would identify it
        assert "joint q5 moves over 0.957 deg in the data" in w.sentence()
        i = res.names.index(w.name)
        assert abs(res.theta[i] - true[w.name]) < 3 * res.std[i]


def test_default_calibration_of_the_narrow_file_names_what_the_prior_holds(narrow_file, capsys,
                                                                         tmp_path):
    j = tmp_path / "res.json"
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", narrow_file, "--json", j,
                            "-o", tmp_path / "cal.yaml")
    assert code == 0, err
    text = " ".join(stdout.split())
    assert "Held by the prior (weakly identifiable): 3 parameter(s)" in text
    assert "q5 over its range" in text and "0.957" in text
    doc = json.loads(j.read_text())
    assert doc["verdict"]["trusted"] and len(doc["held_by_prior"]) == 3
    assert doc["held_by_prior"][0]["joint"] == "q5"


def test_the_weak_parameter_table_follows_si(narrow_file, capsys, tmp_path):
    """--si prints the prior-held table in m and rad like every other table of calibrate."""
    code, stdout, err = run(capsys, "calibrate", "puma560", "--data", narrow_file, "--si",
                            "-o", tmp_path / "cal.yaml")
    assert code == 0, err
    text = " ".join(stdout.split())
    assert "(moves 0.0167" in text and "3.49 rad)" in text        # q5's 0.957 of 200 deg
    assert "0.957" not in text and " deg" not in text


@pytest.mark.parametrize("stated", [1.0, 0.05, 0.01])
def test_noise_stated_far_too_small_is_warned_not_refused(stated):
    """The same data (0.02 mm noise) with the noise stated right, 10x and 50x too small:
    sigma0 follows the ratio, and the warning comes exactly when sigma0 is more than 10
    times what the noise alone explains; the calibration stays trusted (the residual is
    within what the tolerances allow) and its estimate does not depend on the statement."""
    from kincal.identify.checks import UNDERSTATED_NOISE

    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    truth = perturb_robot(robot, rng, length_std=1e-4, angle_std=1e-4, offset_std=1e-4)
    q = random_configurations(robot, 100, rng)
    block = simulate_positions(truth, q, rng, noise_std=2e-5, sigma=2e-5 * stated)
    res = calibrate(robot, [block])
    p = res.problem
    v = judge(res, resolve_tolerances(p.names, p.units, p.roles).sigma)
    assert v.trusted, v.line()
    assert res.sigma0 == pytest.approx(1.0 / stated, rel=0.25)
    warned = [w for w in v.warnings() if "times the stated noise" in w]
    assert bool(warned) == (stated < 1 / UNDERSTATED_NOISE / 1.3), (res.sigma0, warned)
    same = calibrate(robot, [block.__class__(block.q, block.positions, 2e-5, block.name)])
    assert np.allclose(res.theta, same.theta, atol=1e-12)    # the statement moves nothing
    assert np.allclose(res.std, same.std, rtol=1e-6)         # std scaled by sigma0
