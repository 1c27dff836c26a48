"""The gate for data the model cannot explain (issue "never silently wrong").

Every case is first a file a user could have written (a simulated PUMA 560 measured by a
tracker, 10 um noise, known truth), then broken the way real files break:

* joint readings beyond the robot's limits (one reading replaced by 300 deg where the
  limit is 225 deg), named by file, line and joint, in ``calibrate``, ``validate`` and
  ``fk`` / ``jacobian``;
* degree values under ``_rad`` headers, and radian values under ``_deg`` headers;
* a residual the noise and the tolerances cannot explain (two joint columns swapped);
* no redundancy: one row, two rows, one row repeated 212 times;
* nothing to estimate (``--free ,``, ``--fix '*'``) and loss scales that are not a positive
  finite number: bad input.

Refusals exit 1 with one line and write no calibrated robot unless ``--force``; bad input
exits 2 with one line and writes nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import invoke, run
from scipy.stats import chi2

from kincal.errors import CheckFailedError, KincalError
from kincal.identify.checks import (
    MODEL_FLOOR,
    RESIDUAL_TAIL,
    distinct_equations,
    judge,
    residual_bound,
)
from kincal.identify.solver import calibrate
from kincal.identify.tolerances import resolve_tolerances
from kincal.measure.base import stack
from kincal.measure.data_checks import (
    LIMIT_SHARE,
    block_joint_problems,
    command_line_joints,
    joint_data_line,
    limit_problems,
    refuse_joint_data,
    unit_problems,
)
from kincal.robots.files import load_serial_robot
from kincal.workflow.flow import read_blocks, run_flow

PUMA = load_serial_robot("puma560")


# --------------------------------------------------------------------------- files
@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A good simulated file (rad, m) and its broken versions."""
    d = tmp_path_factory.mktemp("gate")
    good = d / "good.csv"
    assert invoke("simulate", "puma560", "-o", good, "-n", "60", "--seed", "4",
                  "--truth", d / "truth.yaml") == 0
    lines = good.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("q1")]
    rows = [ln.split(",") for ln in lines if ln not in head]
    out = {"good": good}

    def write(name: str, body: list[list[str]], header: list[str] = head) -> None:
        out[name] = d / f"{name}.csv"
        out[name].write_text("\n".join(header + [",".join(r) for r in body]) + "\n")

    deg = [[f"{math.degrees(float(v)):.10g}" if i < 6 else v for i, v in enumerate(r)]
           for r in rows]
    write("deg_as_rad", deg)                           # degrees under _rad headers
    write("rad_as_deg", rows, [h.replace("_rad", "_deg") for h in head])
    write("deg_ok", deg, [h.replace("_rad", "_deg") for h in head])
    beyond = [list(r) for r in rows]
    beyond[3][1] = repr(math.radians(300.0))           # q2 = 300 deg, limit 225 deg
    write("beyond", beyond)
    swapped = [[r[1], r[0], *r[2:]] for r in rows]     # q1 and q2 columns swapped
    write("swapped", swapped)
    write("one", rows[:1])
    write("two", rows[:2])
    write("same", [rows[0]] * 212)
    return out


def code_err(capsys, *args: object) -> tuple[int, str]:
    code, _, err = run(capsys, *args)
    return code, err.strip()


def one_line(err: str) -> str:
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


# --------------------------------------------------------------------------- joint limits
def test_limit_problems_name_the_line_the_joint_and_the_limits():
    lo, hi = (math.degrees(v) for v in PUMA.joint_limits[1])      # q2: -45 .. 225 deg
    q = np.zeros((5, 6))
    q[2, 1] = math.radians(300.0)
    q[4, 1] = math.radians(hi + 0.5 * LIMIT_SHARE * (hi - lo))      # within the slack
    found = limit_problems(PUMA, q, "f.csv", lines=[10, 11, 12, 13, 14])
    assert len(found) == 1 and found[0].joints == ("q2",)
    assert found[0].line() == ("f.csv: line 12: joint q2 = 300 deg is beyond its limits "
                               f"[{lo:.4g} deg, {hi:.4g} deg]")
    q[4, 1] = math.radians(hi + 2 * LIMIT_SHARE * (hi - lo))        # beyond the slack
    assert "(2 of 5 rows beyond)" in limit_problems(PUMA, q, "f.csv")[0].words


def test_a_robot_without_limits_is_not_checked_for_limits():
    motoman = load_serial_robot("motoman_right")
    assert not np.isfinite(motoman.joint_limits).any()
    q = np.full((4, motoman.n), 5.0)                # 286 deg on every joint
    assert limit_problems(motoman, q, "f.csv") == []


def test_calibrate_refuses_a_reading_beyond_the_limits(files, capsys, tmp_path):
    out = tmp_path / "cal.yaml"
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["beyond"], "-o", out)
    line = one_line(err)
    # line 7 of the file: 2 comment lines, the header, then the 4th row
    assert code == 1 and f"{files['beyond']}: line 7: joint q2 = 300 deg is beyond" in line
    assert "--force" in line and not out.exists()
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["beyond"], "-o", out,
                         "--force")
    assert code == 1 and out.exists() and "written anyway" in one_line(err)


def test_validate_refuses_a_file_beyond_the_limits(files, capsys, tmp_path):
    j = tmp_path / "v.json"
    code, err = code_err(capsys, "validate", "puma560", "--data", files["beyond"], "--json", j)
    assert code == 1 and "line 7: joint q2 = 300 deg" in one_line(err) and not j.exists()
    code, err = code_err(capsys, "validate", "puma560", "--data", files["good"])
    assert code == 0, err


def test_fk_says_loudly_that_bare_numbers_beyond_the_limits_are_radians(capsys):
    code, out, err = run(capsys, "fk", "puma560", "--q", "10,20,30,40,50,60")
    line = one_line(err.strip())
    assert code == 1 and "position" in out                 # the answer, then the refusal
    assert "option --q: joint q1 = 573 deg is beyond its limits" in line
    assert "read as radians" in line and "--deg" in line
    assert run(capsys, "fk", "puma560", "--q", "10,20,30,40,50,60", "--deg")[0] == 0
    code, _, err = run(capsys, "jacobian", "puma560", "--q", "0,300,0,0,0,0", "--deg")
    assert code == 1 and "joint q2 = 300 deg" in one_line(err.strip())
    assert "radians" not in err
    assert command_line_joints(PUMA, np.zeros(6)) == ""


# --------------------------------------------------------------------------- angle units
def test_degrees_under_rad_headers_are_named(files):
    blocks = read_blocks([files["deg_as_rad"]], PUMA)
    found = block_joint_problems(PUMA, blocks)
    assert [p.kind for p in found] == ["unit"]          # the limits follow from the unit
    assert set(found[0].joints) == {f"q{i}" for i in range(1, 7)}
    assert "look like degrees" in found[0].words and "(read in rad)" in found[0].words


def test_radians_under_deg_headers_are_named_and_degrees_pass(files):
    found = block_joint_problems(PUMA, read_blocks([files["rad_as_deg"]], PUMA))
    assert [p.kind for p in found] == ["unit"] and "look like radians" in found[0].words
    assert block_joint_problems(PUMA, read_blocks([files["deg_ok"]], PUMA)) == []
    assert block_joint_problems(PUMA, read_blocks([files["good"]], PUMA)) == []


def test_one_pose_repeated_in_degrees_is_not_a_unit_problem():
    q = np.tile(np.radians([1.0, 2.0, -1.0, 0.5, 1.0, 2.0]), (30, 1))   # one small pose
    assert unit_problems(PUMA, q, "f.csv", ["deg"] * 6) == []
    q[::2, 0] += math.radians(1.0)                                       # it moved: radians
    assert unit_problems(PUMA, q, "f.csv", ["deg"] * 6)[0].kind == "unit"


def test_a_ur_joint_may_span_two_turns_in_radians():
    ur = load_serial_robot("ur5e")                          # limits +-360 deg
    q = np.zeros((3, 6))
    q[:, 0] = [-6.0, 0.0, 6.0]                       # 12 rad: inside its range
    assert unit_problems(ur, q, "f.csv", ["rad"] * 6) == []
    q[:, 0] = [-120.0, 0.0, 120.0]                   # 240: degrees
    found = unit_problems(ur, q, "f.csv", ["rad"] * 6)
    assert [(p.kind, p.joints) for p in found] == [("unit", (ur.joints[0].name,))]


def test_calibrate_refuses_degrees_under_rad_headers(files, capsys, tmp_path):
    out = tmp_path / "cal.yaml"
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["deg_as_rad"],
                         "-o", out)
    line = one_line(err)
    assert code == 1 and not out.exists()
    assert "look like degrees" in line and "the model cannot explain the data" in line


def test_joint_data_line_names_each_file_once():
    q = np.zeros((2, 6))
    q[:, 0] = q[:, 1] = 9.0
    line = joint_data_line(limit_problems(PUMA, q, "a.csv") * 2, limit=3)
    assert line.count("a.csv") == 1 and line.endswith("and 1 more")
    with pytest.raises(CheckFailedError):
        refuse_joint_data(PUMA, [type("B", (), {"q": q, "name": "b"})()])


# --------------------------------------------------------------------------- residual
def _tolerances(prob):
    return resolve_tolerances(prob.names, prob.units, prob.roles, PUMA.meta.get("tolerances"))


def _fit(path: Path):
    blocks = read_blocks([path], PUMA)
    res = calibrate(PUMA, blocks)
    prob, _ = stack(PUMA, blocks)
    tols = _tolerances(prob).sigma
    return res, tols


def test_residual_bound_is_the_chi_square_quantile_times_the_model_floor(files):
    """The tolerance term against an independent estimate: the mean squared change of the
    whitened residuals when the robot's geometry moves by random errors of its tolerances
    (Monte Carlo, linear for such small errors)."""
    res, tols = _fit(files["good"])
    dof = 100
    bound = residual_bound(res, tols, dof)
    q = chi2.isf(RESIDUAL_TAIL, dof) / dof
    v_tol = ((bound**2 / q) - 1.0) / MODEL_FLOOR**2
    prob = res.problem
    geo = [j for j in range(prob.num_robot) if tols.get(prob.names[j])]
    rng = np.random.default_rng(0)
    r0 = prob.residuals(res.theta)
    draws = []
    for _ in range(300):
        th = res.theta.copy()
        th[geo] += rng.normal(0.0, [tols[prob.names[j]] for j in geo])
        draws.append(np.mean((prob.residuals(th) - r0) ** 2))
    mc = float(np.mean(draws))
    assert v_tol == pytest.approx(mc, rel=4 / math.sqrt(300) + 0.05)
    assert residual_bound(res, {}, dof) is None               # no tolerances: no floor


def test_a_good_fit_is_trusted_and_swapped_columns_are_not(files, capsys, tmp_path):
    res, tols = _fit(files["good"])
    assert judge(res, tols).trusted and res.sigma0 < 1.5      # the stated noise is right
    res, tols = _fit(files["swapped"])
    v = judge(res, tols)
    kinds = [r.kind for r in v.refusals]
    assert "residual" in kinds and not v.trusted
    r = v.refusals[kinds.index("residual")]
    assert r.numbers["sigma0"] > r.numbers["bound"] and "swapped" in r.sentence
    out = tmp_path / "cal.yaml"
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["swapped"], "-o", out)
    assert code == 1 and "cannot explain" in one_line(err) and not out.exists()
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["good"], "-o", out)
    assert code == 0 and out.exists(), err


def test_run_flow_checks_the_held_out_files_too(files):
    robot = PUMA
    flow = run_flow(robot, read_blocks([files["good"]], robot),
                    read_blocks([files["beyond"]], robot))
    assert not flow.trusted and flow.verdict is not None
    assert [r.kind for r in flow.verdict.refusals] == ["data"]
    assert flow.verdict.to_dict()["refusals"][0]["kind"] == "data"


# --------------------------------------------------------------------------- redundancy
@pytest.mark.parametrize("name, configurations", [("one", 1), ("two", 2), ("same", 1)])
def test_no_redundancy_is_refused(files, capsys, tmp_path, name, configurations):
    out = tmp_path / "cal.yaml"
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files[name], "-o", out)
    line = one_line(err)
    assert code == 1 and not out.exists()
    assert f"no redundancy: {3 * configurations} equations from {configurations} distinct" \
        in line


def test_distinct_equations_count_each_configuration_once(files):
    blocks = read_blocks([files["same"]], PUMA)
    assert distinct_equations(blocks) == (3, 1)
    r = np.ones(3 * 212)
    assert distinct_equations(blocks, r) == (3, 1)              # copies: one row
    r[3:] += np.repeat(np.arange(1, 212), 3) * 1e-3             # new noise each time
    assert distinct_equations(blocks, r) == (3 * 212, 1)        # a repeatability test
    blocks = read_blocks([files["good"]], PUMA)
    assert distinct_equations(blocks) == (180, 60)


def test_one_pose_seen_from_several_stations_is_redundant(tmp_path):
    """A range instrument (one distance per station): 30 poses, 4 stations, 120 rows with
    each pose 4 times; 32 parameters are estimated and the fit is redundant."""
    path = tmp_path / "r.csv"
    assert invoke("simulate", "puma560", "-o", path, "-i", "range", "--poses", "30",
                  "--seed", "4") == 0
    blocks = read_blocks([path], PUMA)
    flow = run_flow(PUMA, blocks)
    assert distinct_equations(blocks) == (30, 30)               # the poses alone: 30
    assert distinct_equations(blocks, flow.result.residuals)[0] == 120
    assert flow.trusted, flow.verdict.line()


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("options, words", [
    (["--free", ","], "option --free ',': names no parameter"),
    (["--fix", "*"], "option --fix '*': every candidate parameter is fixed"),
    (["--free", "tracker.x", "--fix", "tracker.*"], "every candidate parameter is fixed"),
    (["--loss-scale", "0"], "option --loss-scale: 0.0 is not a positive finite"),
    (["--loss-scale", "-1"], "option --loss-scale: -1.0"),
    (["--loss-scale", "nan"], "option --loss-scale: nan"),
])
def test_nothing_to_estimate_is_bad_input(files, capsys, tmp_path, options, words):
    out, j = tmp_path / "cal.yaml", tmp_path / "r.json"
    code, err = code_err(capsys, "calibrate", "puma560", "--data", files["good"], "-o", out,
                         "--json", j, *options)
    assert code == 2 and words in one_line(err)
    assert not out.exists() and not j.exists()


def test_run_flow_refuses_zero_free_parameters(files):
    with pytest.raises(KincalError, match="nothing to estimate"):
        run_flow(PUMA, read_blocks([files["good"]], PUMA), free=",")


def test_nothing_estimated_is_refused_by_the_verdict(files):
    """The library takes ``free=[]`` (the nominal robot comes back): its verdict refuses."""
    blocks = read_blocks([files["good"]], PUMA)
    res = calibrate(PUMA, blocks, free=[])
    prob, _ = stack(PUMA, blocks)
    assert res.estimated == []
    v = judge(res, _tolerances(prob).sigma)
    assert [r.kind for r in v.refusals] == ["nothing"] and not v.trusted
    assert v.short() == "nothing estimated"


def test_the_real_files_pass_the_joint_checks():
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "motoman_leica"
    path = data / "right_arm_grid_6x6x6.csv"
    if not path.is_file():
        pytest.skip("real data not found")
    robot = load_serial_robot("motoman_right")
    assert block_joint_problems(robot, read_blocks([path], robot)) == []
