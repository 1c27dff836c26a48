"""Robot parameters with a fixed camera (eye-to-hand): the board on the Panda's flange,
the camera fixed in the world, known joint-offset and link errors; pixels are the exact
projection plus Gaussian noise.  Truth is the simulated robot."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.hand_eye_fixed import BoardOnFlangeMeasurement, fixed_camera_robot_start
from kincal.identify.hand_eye_lens import calibrate_board_camera, project_lens
from kincal.measure.camera_board import Board
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
LENS = np.array([640.0, 641.0, 645.0, 355.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SIZE = (1280, 720)
Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
BOARD_ON_FLANGE = matrix_from_frame([0.0, 0.0, 0.05, 0.0, 0.0, np.pi])
TRUTH = {"theta_offset[2]": -0.009, "theta_offset[3]": -0.0126, "theta_offset[4]": -0.0064,
         "theta_offset[5]": 0.0126, "theta_offset[6]": -0.0085, "a[4]": 0.001,
         "d[5]": -0.0012}
FREE = ["theta_offset*", "a[4]", "d[5]"]


def simulate(n: int, noise: float, rng: np.random.Generator, corners: int = 24):
    """``n`` images of the board on the flange of the true robot from a fixed camera
    0.6 m away; returns the nominal robot, the joints, points, pixels and the camera."""
    nominal = load_serial_robot("panda")
    true = nominal.with_params(TRUTH)
    camera = (true.fk(Q0) @ BOARD_ON_FLANGE @ matrix_from_frame([0.07, 0.1, 0.6, 0.3, np.pi,
                                                                  0.0]))
    pts = BOARD.corner_points(np.arange(corners))
    q, uv = [], []
    while len(q) < n:
        qi = Q0 + rng.uniform(-0.35, 0.35, 7)
        B = inverse(camera) @ true.fk(qi) @ BOARD_ON_FLANGE
        x = pts @ B[:3, :3].T + B[:3, 3]
        p = project_lens(x, LENS)
        if np.all(x[:, 2] > 0.1) and np.all((p > 5) & (p < np.array(SIZE) - 5)):
            q.append(qi)
            uv.append(p + rng.normal(0.0, noise, p.shape))
    return nominal, np.array(q), [pts] * n, uv, camera


def test_board_on_flange_jacobian_is_the_derivative() -> None:
    """Analytic Jacobians (robot parameters, camera pose) against central differences."""
    nominal, q, pts, uv, camera = simulate(3, 0.0, np.random.default_rng(0), corners=8)
    block = BoardOnFlangeMeasurement("camera", np.repeat(q, 8, axis=0), np.vstack(pts),
                                     np.vstack(uv), 0.5, LENS[:4])
    robot = nominal.with_params({"tool.z": 0.107 + 0.05})
    extra = block.initial_guess(robot)
    _, Jr, Je = block.evaluate(robot, extra)
    assert Jr is not None and Je is not None
    h = 1e-7
    for k in (8, 12, 25, 30, 36):                  # offsets, a, d and a tool parameter
        p = robot.param_values.copy()
        p[k] += h
        rp = block.evaluate(robot.with_params(p), extra, False)[0]
        p[k] -= 2 * h
        rm = block.evaluate(robot.with_params(p), extra, False)[0]
        assert np.allclose(Jr[:, k], (rp - rm) / (2 * h), atol=1e-4 * np.abs(Jr).max())
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        num = (block.evaluate(robot, extra + d, False)[0]
               - block.evaluate(robot, extra - d, False)[0]) / (2 * h)
        assert np.allclose(Je[:, k], num, atol=1e-4 * np.abs(Je).max())


def test_joint_offsets_and_links_recovered_within_the_stated_error() -> None:
    """Monte Carlo, 3 sets of 12 images (0.3 px): the first and last joint offsets are
    named as held (camera rz, board rz); the 7 others recovered, the RMS of
    (estimate - truth) / stated std over the 21 estimates within 0.55..1.5 (chi with
    about 20 degrees of freedom); camera within 4 expected errors."""
    z = []
    for seed in range(3):
        nominal, q, pts, uv, camera = simulate(12, 0.3, np.random.default_rng(100 + seed))
        fit = calibrate_board_camera(nominal.fk(q), pts, uv, [f"{k:02d}" for k in range(12)],
                                     LENS, "fixed", 0.0, fit_lens=(), sigma=0.3,
                                     robot=nominal, q=q, free=FREE)
        assert set(fit.robot) == set(TRUTH)
        assert set(fit.held) == {"theta_offset[1]", "theta_offset[7]"}
        assert "camera.camera" in fit.held["theta_offset[1]"]
        assert "tool.rz" in fit.held["theta_offset[7]"]
        z += [(v - TRUTH[n]) / s for n, (v, s) in fit.robot.items()]
        assert np.linalg.norm(fit.X[:3, 3] - camera[:3, 3]) < 4 * fit.expected_position
    assert 0.55 < np.sqrt(np.mean(np.square(z))) < 1.5, z


def test_what_the_images_fix_worse_than_its_tolerance_is_held_and_named() -> None:
    """Four images at 3 px: no robot parameter is fixed better than its tolerance; each
    is held at nominal and named with the standard error the images would give."""
    nominal, q, pts, uv, camera = simulate(4, 3.0, np.random.default_rng(7))
    start = fixed_camera_robot_start(nominal, q, pts, uv, LENS, FREE, 3.0)
    assert start.names == []
    for n in TRUTH:
        why = start.held[n]
        unit = "mm" if n[0] in "ad" else "deg"
        assert f"no better than its tolerance {1 if unit == 'mm' else 0.5} {unit}" in why, why
        assert float(why.split("only to ")[1].split()[0]) > (1.0 if unit == "mm" else 0.5)
    assert np.linalg.norm(start.X[:3, 3] - camera[:3, 3]) < 0.05


def test_without_joints_robot_parameters_are_refused() -> None:
    nominal, q, pts, uv, _ = simulate(4, 0.3, np.random.default_rng(3), corners=8)
    with pytest.raises(Exception, match="joint values"):
        calibrate_board_camera(nominal.fk(q), pts, uv, list("abcd"), LENS, "fixed", 0.0,
                               fit_lens=(), sigma=0.3, free=["theta_offset*"])


def test_cli_fixed_camera_with_joints_fits_the_offsets_and_names_the_held(tmp_path,
                                                                        capsys) -> None:
    """`kincal hand-eye panda --images --joints --mount fixed --free 'theta_offset*'` on 6
    rendered images (perspective warp of the board, blur, noise) of a board on the flange
    of a Panda with joint-offset errors: the offsets within 4 stated standard errors, the
    first and last named as held, in the console and the JSON."""
    cv2 = pytest.importorskip("cv2")
    import json

    from cli_helpers import run
    from test_camera_images import MARGIN, PX, _render

    board = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
    (tmp_path / "board.yaml").write_text("type: charuco\nsquares: [5, 7]\nsquare: 34 mm\n"
                                         "marker: 28 mm\ndictionary: DICT_6X6_250\n")
    (tmp_path / "cam.yaml").write_text("camera_matrix: {rows: 3, cols: 3, data: [640, 0, "
                                       "645, 0, 641, 355, 0, 0, 1]}\n")
    Kt = np.array([[640.0, 0, 645], [0, 641.0, 355], [0, 0, 1]])
    S = np.array([[PX / board.square, 0, MARGIN - 0.5], [0, PX / board.square, MARGIN - 0.5],
                  [0, 0, 1]])
    nominal = load_serial_robot("panda")
    offsets = {k: v for k, v in TRUTH.items() if k.startswith("theta")}
    true = nominal.with_params(offsets)
    on_flange = matrix_from_frame([0.0, 0.0, 0.05, 0.0, 0.0, np.pi])  # OpenCV: z into board
    camera = true.fk(Q0) @ on_flange @ matrix_from_frame([0.07, 0.1, -0.45, 0.3, 0.0, 0.0])
    pts = board.corner_points(np.arange(board.num_corners))
    rng = np.random.default_rng(11)
    (tmp_path / "img").mkdir()
    rows = ["image," + ",".join(f"q{k + 1}_rad" for k in range(7))]
    while len(rows) < 7:
        q = Q0 + rng.uniform(-0.3, 0.3, 7)
        B = inverse(camera) @ true.fk(q) @ on_flange
        x = pts @ B[:3, :3].T + B[:3, 3]
        uv = x[:, :2] / x[:, 2:] * 640 + [645, 355]
        if (B[:3, 2] @ B[:3, 3] / np.linalg.norm(B[:3, 3]) < 0.7 or uv.min() < 40
                or uv[:, 0].max() > 1240 or uv[:, 1].max() > 680):
            continue
        H = Kt @ np.column_stack([B[:3, 0], B[:3, 1], B[:3, 3]]) @ np.linalg.inv(S)
        name = f"{len(rows):02d}.png"
        cv2.imwrite(str(tmp_path / "img" / name), _render(cv2, board, H / H[2, 2], rng))
        rows.append(name + "," + ",".join(f"{v:.9f}" for v in q))
    (tmp_path / "joints.csv").write_text("\n".join(rows) + "\n")
    code, out, err = run(capsys, "hand-eye", "panda", "--images", tmp_path / "img", "--board",
                         tmp_path / "board.yaml", "--joints", tmp_path / "joints.csv",
                         "--mount", "fixed", "--intrinsics", tmp_path / "cam.yaml", "--lens",
                         "none", "--holdout", "0", "--free", "theta_offset*", "--json",
                         tmp_path / "f.json")
    assert code == 0, err
    assert "held at nominal: theta_offset[1]" in out and "robot parameters fitted" in out
    doc = json.loads((tmp_path / "f.json").read_text())
    assert set(doc["robot_parameters_held"]) == {"theta_offset[1]", "theta_offset[7]"}
    fitted = doc["robot_parameters"]
    assert set(fitted) == set(offsets)
    for n, v in fitted.items():
        assert abs(v["value"] - offsets[n]) < 4 * v["std"], (n, v, offsets[n])
