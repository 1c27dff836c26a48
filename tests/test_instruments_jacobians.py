"""Analytic Jacobians of every instrument model against central finite differences,
and the closed-form initial guesses against the truth."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from kincal.measure.instruments import (
    BearingMeasurement,
    CameraMeasurement,
    FixtureMeasurement,
    HandCameraMeasurement,
    PlaneMeasurement,
    RangeMeasurement,
)
from kincal.measure.instruments.common import to_local, to_world
from kincal.measure.simulate import perturb_robot
from kincal.robots.files import load_serial_robot
from kincal.spatial import matrix_from_frame

ROBOT = perturb_robot(load_serial_robot("puma560"), np.random.default_rng(3), length_std=0.01,
                      angle_std=0.02, base_std=(0.05, 0.1), tool_std=(0.05, 0.1))
RNG = np.random.default_rng(42)
N = 12
Q = RNG.uniform(-1.5, 1.5, (N, 6))
ST = ["a", "b", "c"] * 4
KS = {"a": (800.0, 810.0, 320.0, 240.0), "b": (700.0, 700.0, 300.0, 200.0),
      "c": (600.0, 650.0, 320.0, 240.0)}


def station_values(k: int, rng: np.random.Generator) -> np.ndarray:
    """Frames 2 m away with arbitrary orientations (6 values each)."""
    return np.concatenate([np.r_[rng.uniform(-2, 2, 3), rng.uniform(-3, 3, 3)]
                           for _ in range(k)])


def blocks() -> dict[str, tuple[object, np.ndarray]]:
    rng = np.random.default_rng(7)
    mk = rng.uniform(-0.1, 0.1, 3)
    planes = {"x": ((1, 0.1, 0), 0.3, False), "y": ((0, 1, 0.1), 0.2, True),
              "z": ((0.1, 0.2, 1), -0.1, False)}
    return {
        "range": (RangeMeasurement("r", Q, ST, RNG.uniform(1, 2, N), 1e-3),
                  np.r_[rng.uniform(-2, 2, 9), mk]),
        "range-incremental": (RangeMeasurement(
            "r", Q, ST, RNG.uniform(-1, 1, N), 1e-3, ["absolute", "incremental"] * 6,
            ["0", "0", "1", "1"] * 3), np.r_[rng.uniform(-2, 2, 9), rng.uniform(1, 2, 6), mk]),
        "range-tool": (RangeMeasurement("r", Q, ST, RNG.uniform(1, 2, N), 1e-3, marker="tool"),
                       rng.uniform(-2, 2, 9)),
        "bearing": (BearingMeasurement("b", Q, ST, RNG.uniform(-1, 1, (N, 2)), 1e-4),
                    np.r_[station_values(3, rng), mk]),
        "bearing-tool": (BearingMeasurement("b", Q, ST, RNG.uniform(-1, 1, (N, 2)), 1e-4,
                                            marker="tool"), station_values(3, rng)),
        "camera": (CameraMeasurement("c", Q, ST, RNG.uniform(0, 500, (N, 2)), 0.5, KS),
                   np.r_[station_values(3, rng), mk]),
        "camera-hand": (HandCameraMeasurement("h", Q, RNG.normal(0, 0.1, (N, 3)),
                                              RNG.uniform(0, 500, (N, 2)), 0.5, KS["a"]),
                        station_values(1, rng)),
        "plane": (PlaneMeasurement("p", Q, ["x", "y", "z"] * 4, 1e-4, planes),
                  np.r_[0.05, -0.03, 0.3, -0.02, 0.04, -0.1, mk]),
        "fixture": (FixtureMeasurement("f", Q, RNG.normal(size=(N, 3)), 1e-4), mk),
        "fixture-tool": (FixtureMeasurement("f", Q, RNG.normal(size=(N, 3)), 1e-4,
                                            marker="tool"), np.zeros(0)),
    }


BLOCKS = blocks()


def central(fun, x: np.ndarray, h: float) -> np.ndarray:
    cols = []
    for j in range(len(x)):
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        cols.append((fun(xp) - fun(xm)) / (2 * h))
    return np.column_stack(cols) if cols else np.zeros((fun(x).size, 0))


@pytest.mark.parametrize("key", list(BLOCKS))
def test_jacobians_match_central_differences(key: str) -> None:
    block, extra = BLOCKS[key]
    assert len(extra) == len(block.parameters())
    r, Jr, Je = block.evaluate(ROBOT, extra)
    assert r.shape == (block.residual_owner().size,)
    assert Jr.shape == (r.size, ROBOT.num_params) and Je.shape == (r.size, len(extra))
    h = 1e-6
    fd_r = central(lambda p: block.evaluate(ROBOT.with_params(p), extra, False)[0],
                   ROBOT.param_values.copy(), h)
    fd_e = central(lambda e: block.evaluate(ROBOT, e, False)[0], extra.astype(float), h)
    # central differences are accurate to ~h^2 * third derivative + roundoff / h
    scale_r = max(np.abs(Jr).max(), 1.0)
    scale_e = max(np.abs(Je).max(), 1.0) if Je.size else 1.0
    assert np.abs(Jr - fd_r).max() < 1e-7 * scale_r
    if Je.size:
        assert np.abs(Je - fd_e).max() < 1e-7 * scale_e


def test_incremental_offsets_per_station_and_run() -> None:
    block, _ = BLOCKS["range-incremental"]
    names = block.parameters().names
    # stations a, b, c each have incremental rows in runs 0 and 1 -> six offsets
    assert sorted(n for n in names if ".L0" in n) == sorted(
        f"r.{s}.L0.{k}" for s in "abc" for k in "01")
    one_run = RangeMeasurement("r", Q, ST, np.zeros(N), 1e-3, ["incremental"] * N)
    assert [n for n in one_run.parameters().names if "L0" in n] == ["r.a.L0", "r.b.L0",
                                                                      "r.c.L0"]


def test_residuals_are_whitened_differences() -> None:
    block, extra = BLOCKS["range"]
    r = block.evaluate(ROBOT, extra, False)[0]
    T = ROBOT.fk(Q)
    p = T[:, :3, 3] + T[:, :3, :3] @ extra[-3:]
    S = extra[:9].reshape(3, 3)[block.station_index]
    rho = np.linalg.norm(p - S, axis=1)
    assert np.allclose(r, (rho - block.obs[:, 0]) / 1e-3, rtol=1e-12, atol=1e-9)


def test_frame_helpers_are_inverse() -> None:
    rng = np.random.default_rng(0)
    f = station_values(1, rng)
    s = rng.normal(size=(5, 3))
    w, _ = to_world(f, s, False)
    x, _, _ = to_local(f[None], np.zeros(5, dtype=np.intp), w, False)
    assert np.allclose(x, s, atol=1e-12)
    T = matrix_from_frame(f)
    assert np.allclose(w, s @ T[:3, :3].T + T[:3, 3], atol=1e-12)


SIM_CASES = {
    "range": ("simulate_range", {"stations": 3}),
    "range-incremental": ("simulate_range", {"incremental": True}),
    "bearing": ("simulate_bearing", {}),
    "camera": ("simulate_camera", {}),
    "camera-hand": ("simulate_camera", {"mount": "hand"}),
    "plane": ("simulate_plane", {}),
    "plane-known": ("simulate_plane", {"known": True}),
    "fixture": ("simulate_fixture", {}),
}


@pytest.mark.parametrize("key", list(SIM_CASES))
def test_initial_guess_recovers_the_instrument(key: str) -> None:
    """With the true robot, the closed-form guess (+ block-only Gauss-Newton) is exact."""
    from kincal.measure import instruments

    fn, opts = SIM_CASES[key]
    blocks, truth = getattr(instruments, fn)(ROBOT, np.random.default_rng(5), 30, 0.0, **opts)
    block = blocks[0]
    names = block.parameters().names
    assert set(names) == set(truth)
    guess = block.initial_guess(ROBOT)
    want = np.array([truth[n] for n in names])
    assert np.abs(guess - want).max() < 1e-8
    assert np.abs(block.evaluate(ROBOT, want, False)[0]).max() < 1e-6


@pytest.mark.parametrize("key", list(BLOCKS))
def test_pieces_equal_the_whole(key: str) -> None:
    """Evaluated in pieces of a few rows (as large blocks are), every residual and
    Jacobian column is the whole block's, in order; the block-only pieces of the initial
    guess's refinement are its own columns."""
    from kincal.measure.instruments.pointblock import _own_pieces

    block, extra = BLOCKS[key]
    r, Jr, Je = block.evaluate(ROBOT, extra)
    k = r.size // N
    pieces = list(block.evaluate_chunks(ROBOT, extra, rows=2 * k + 1))
    if not hasattr(block, "own_pieces"):                  # one piece: the whole block
        assert len(pieces) == 1
    else:
        assert len(pieces) == -(-N // ((2 * k + 1) // k))
    assert [sl.start for sl, *_ in pieces] == sorted(sl.start for sl, *_ in pieces)
    assert np.array_equal(np.concatenate([p[1] for p in pieces]), r)
    assert np.array_equal(np.concatenate([p[2] for p in pieces]), Jr)
    assert np.array_equal(np.concatenate([p[3] for p in pieces]), Je)
    own = list(_own_pieces(block, ROBOT, extra, True))
    assert np.allclose(np.concatenate([o[0] for o in own]), r, rtol=1e-14, atol=0)
    assert np.allclose(np.concatenate([o[1] for o in own]), Je, rtol=1e-14, atol=1e-300)


def test_every_row_field_is_declared() -> None:
    """Each point instrument declares all its per-row attributes (else it would be
    evaluated whole: correct, but not in pieces)."""
    for key, (block, _) in BLOCKS.items():
        if hasattr(block, "_undeclared_rows"):
            assert block._undeclared_rows() == [], key


def test_an_undeclared_row_field_keeps_the_block_whole() -> None:
    block, extra = BLOCKS["range"]
    odd = copy.copy(block)
    odd.weights_per_row = np.ones(N)                     # a plug-in's own per-row data
    assert len(list(odd.evaluate_chunks(ROBOT, extra, rows=3))) == 1
