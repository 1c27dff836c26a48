"""The chain's working memory is the caller's (:class:`kincal.robots.workspace.ChainWorkspace`).

The robot is the immutable model, the workspace the reusable data: a workspace passed
into many evaluations changes no number, never holds a result, stops growing once the
pieces are as large as they get, and two threads with their own workspaces (their own
stacked problems) evaluate the same robot and blocks side by side with the serial
numbers.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

import kincal.robots.workspace as workspace_module
from kincal.measure.base import stack
from kincal.measure.instruments.position import simulate_positions
from kincal.measure.simulate import perturb_robot, random_configurations
from kincal.robots.files import load_serial_robot
from kincal.robots.workspace import ChainWorkspace

INSTRUMENT = [1.5, -0.4, 0.3, 0.2, -0.1, 0.05]


def test_a_shared_workspace_changes_no_number_and_holds_no_result():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(3)
    qa, qb = random_configurations(robot, 700, rng), random_configurations(robot, 700, rng)
    ws = ChainWorkspace()
    Ta, Ja, Jpa = robot.fk_with_jacobians(qa, workspace=ws)
    kept = [a.copy() for a in (Ta, Ja, Jpa)]
    robot.fk_with_jacobians(qb, workspace=ws)                  # same workspace, other q
    for now, then, fresh in zip((Ta, Ja, Jpa), kept, robot.fk_with_jacobians(qa), strict=True):
        assert np.array_equal(now, then) and np.array_equal(now, fresh)
    m, left = np.array([[0.02, -0.03, 0.07], [0.0, 0.05, 0.1]]), np.eye(4)
    left[:3, 3] = [0.3, -0.2, 0.1]
    cols = (0, 3, 5, robot.num_params - 1)
    with_ws = robot.point_jacobian(qa, m, left, cols, rotation=True, workspace=ws)
    alone = robot.point_jacobian(qa, m, left, cols, rotation=True)
    for a, b in zip(with_ws, alone, strict=True):
        assert a is not None and b is not None and np.array_equal(a, b)
    assert np.array_equal(robot.fk(qa, workspace=ws), Ta)


def test_a_workspace_stops_growing_and_problems_do_not_share_one():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(5)
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, 2000, rng)
    prob, theta = stack(robot, [simulate_positions(true, q, rng, 1e-5, INSTRUMENT,
                                                   [0.02, -0.03, 0.07])])
    assert prob.workspace.nbytes == 0
    prob.compressed(theta)
    prob.residuals(theta)
    held = prob.workspace.nbytes
    assert 0 < held <= prob.workspace.max_bytes
    for k in range(3):
        prob.compressed(theta + 1e-6 * k)
        prob.residuals(theta)
    assert prob.workspace.nbytes == held
    other, _ = stack(robot, prob.blocks)
    assert other.workspace is not prob.workspace and other.workspace.nbytes == 0


def test_two_threads_with_their_own_problems_give_the_serial_numbers():
    robot = load_serial_robot("puma560")
    rng = np.random.default_rng(7)
    true = perturb_robot(robot, rng)
    q = random_configurations(robot, 6000, rng)
    block = simulate_positions(true, q, rng, 1e-5, INSTRUMENT, [0.02, -0.03, 0.07])
    _, theta = stack(robot, [block])
    thetas = [theta + 1e-5 * k for k in range(6)]

    def triangle(t: np.ndarray) -> np.ndarray:
        prob, _ = stack(robot, [block])                        # the same block in both threads
        return prob.compressed(t).R

    serial = [triangle(t) for t in thetas]
    with ThreadPoolExecutor(2) as pool:
        threaded = list(pool.map(triangle, thetas))
    for a, b in zip(serial, threaded, strict=True):
        assert np.array_equal(a, b)


def test_the_workspace_module_holds_no_pool():
    """No module-level working memory: the only mutable state is a workspace's own."""
    for name, value in vars(workspace_module).items():
        if not name.startswith("__"):
            assert not isinstance(value, dict | list | np.ndarray), name
    assert not hasattr(workspace_module, "scratch")
