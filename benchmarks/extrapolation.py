"""Extrapolation: is the default calibration still good where it was not trained, and is its
predicted error there right?

For every split below the default calibration (:func:`kincal.workflow.flow.run_flow`, MAP
with the tolerance priors) is fitted on the training part and evaluated on the held-out part
with the training frames (same session: nothing refitted), or for the Panda's artifact on
a new placement (its sockets refitted).  Per split the table gives, inside and outside
the training region (joint ranges or workspace hull of the training data, as the accuracy
model defines it):

* ``nominal``: held-out RMS of the nominal robot with the instrument registered to it on
  the training data [mm];
* ``calibrated``: held-out RMS of the calibrated robot [mm];
* ``predicted``: the accuracy model's predicted RMS, ``sqrt(mean(std^2 + floor^2))``
  (:func:`kincal.identify.accuracy.predict`) [mm], and predicted / measured.

Splits (real data in ``../shared/data``, each skipped when missing):

* Motoman grid: train on 2/3 of the poses whose joints all lie in the inner 60 % of the
  grid's joint ranges; hold out the other third of them and every pose outside;
* TIAGo: train on one day, hold out the other (FIGAROH's protocol), and both days pooled,
  inner 80 % of the joint ranges as above (60 % leaves 7 postures of 99);
* Panda two-socket: train on the ``front`` placement, hold out ``left`` (measured: ball
  distance to its socket's mean; predicted: :func:`~kincal.identify.accuracy.predict_spread`);
* UR10 (IPA): train on series B (joint configurations), hold out series C (random poses),
  every 4th row of each (position of the T-Mac only);
* ROSI two-axis positioner (camera): train on ``|j1| <= 15 deg``, hold out the rest (93
  poses; the target's origin in the camera frame only);
* simulated PUMA 560 with known truth: 60 poses in a +-1 deg or +-3 deg joint box, held
  out 30 poses inside it and 200 in +-90 deg; 8 robots each, pooled; and in a +-10 deg
  box with an unmodelled cyclic joint error (0.02 deg), 6 robots.

Run::

    PYTHONPATH=src python benchmarks/extrapolation.py [--only motoman,sim] [--json out.json]
        [--data ../shared/data]

(about 20 s; ``sim`` is most of it).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from kincal.measure.instruments.position import (  # noqa: E402
    PositionMeasurement,
    simulate_positions,
)
from kincal.measure.simulate import perturb_robot  # noqa: E402
from kincal.robots.files import load_serial_robot  # noqa: E402
from kincal.workflow.flow import read_blocks, run_flow  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TIAGO_UNITS = "x1=m,y1=m,z1=m"
TIAGO_IGNORE = "x2,y2,z2,x3,y3,z3,x4,y4,z4,shipped_row,t_start_robot,t_end_robot,marker_std_mm"


def subset(b: PositionMeasurement, ix: Sequence[int] | np.ndarray) -> PositionMeasurement:
    """The rows ``ix`` of a one-marker position block (same name: the same session)."""
    ix = np.asarray(ix, dtype=np.intp)
    s = np.asarray(b.sigma, dtype=float)
    return PositionMeasurement(b.q[ix], b.positions[ix], s[ix] if s.ndim else float(s), b.name)


def inner_split(q: np.ndarray, frac: float = 0.6, seed: int = 0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Training rows: 2/3 of those whose joints all lie in the inner ``frac`` of the joint
    ranges of ``q``; held out: the rest (the other inner third and all outer rows)."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo) * frac
    inside = np.all((np.abs(q - c) <= h + 1e-12) | (hi - lo < 1e-3), axis=1)
    idx = np.flatnonzero(inside)
    np.random.default_rng(seed).shuffle(idx)
    k = len(idx) * 2 // 3
    return np.sort(idx[:k]), np.sort(np.r_[idx[k:], np.flatnonzero(~inside)])


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float("nan")


def row_of(name: str, split: str, n_train: int, nominal: np.ndarray, calibrated: np.ndarray,
           predicted: np.ndarray, outside: np.ndarray, flow: Any) -> dict[str, Any]:
    """One table row from per-pose errors [m] and the outside mask."""
    flows = getattr(flow, "flows", [flow])
    warned = sum(any(w.startswith("extrapolation:") for w in f.warnings) for f in flows)
    out: dict[str, Any] = {"data": name, "split": split, "train": n_train,
                           "trusted": bool(flow.trusted), "warnings": list(flow.warnings),
                           "extrapolation_warned": f"{warned} of {len(flows)}"
                           if len(flows) > 1 else "yes" if warned else "no"}
    for key, m in (("in", ~outside), ("out", outside)):
        out[f"n_{key}"] = int(m.sum())
        out[f"nominal_{key}"] = _rms(nominal[m])
        out[f"calibrated_{key}"] = _rms(calibrated[m])
        out[f"predicted_{key}"] = _rms(predicted[m])
    return out


def position_split(name: str, split: str, robot: Any, train: Any, held: Any,
                   **options: Any) -> dict[str, Any]:
    """Default calibration on ``train``, evaluated on ``held`` with the training frames."""
    flow = run_flow(robot, [train], [held], validation_frames="training", max_iter=400,
                    **options)
    (f,) = flow.heldout
    n = len(held.q)
    nominal = np.asarray(f.before["position_m"]).reshape(n, -1)[:, 0]
    p = f.prediction
    return row_of(name, split, len(train.q), nominal, f.point_errors, p.predicted_m,
                  p.outside, flow)


# --------------------------------------------------------------------------- data sets
def motoman() -> list[dict[str, Any]]:
    robot = load_serial_robot("motoman_right")
    (b,) = read_blocks([DATA / "motoman_leica" / "right_arm_grid_6x6x6.csv"], robot)
    tr, te = inner_split(b.q)
    return [position_split("Motoman right arm", "grid: inner 60 % of the joint ranges -> "
                           "rest", robot, subset(b, tr), subset(b, te))]


def tiago() -> list[dict[str, Any]]:
    from kincal.robots.urdf import load_urdf

    folder = DATA / "tiago_mocap"
    robot = load_urdf(folder / "tiago_48_schunk.urdf", tip_link="wrist_ft_tool_link")
    (a,) = read_blocks([folder / "train_2021-11-30.csv"], robot, TIAGO_UNITS, [TIAGO_IGNORE])
    (v,) = read_blocks([folder / "validation_2021-11-26.csv"], robot, TIAGO_UNITS,
                       [TIAGO_IGNORE.replace("shipped_row,", "")])
    rows = [position_split("TIAGo", "day 2021-11-30 -> day 2021-11-26", robot,
                           subset(a, np.arange(len(a.q))), subset(v, np.arange(len(v.q))))]
    pooled = PositionMeasurement(np.vstack([a.q, v.q]), np.vstack([a.positions, v.positions]),
                                 1e-3, a.name)
    tr, te = inner_split(pooled.q, 0.8)
    rows.append(position_split("TIAGo", "both days: inner 80 % of the joint ranges -> rest",
                               robot, subset(pooled, tr), subset(pooled, te)))
    return rows


def panda() -> list[dict[str, Any]]:
    from kincal.identify.accuracy import predict
    from kincal.measure.artifacts import (
        ArtifactGeometry,
        ArtifactMeasurement,
        Probe,
        read_socket_files,
    )
    from kincal.robots.urdf import load_urdf

    folder = DATA / "panda_two_socket"
    robot = load_urdf(folder / "panda.urdf", "panda_link0", "panda_hand_tcp")
    ball = load_urdf(folder / "panda.urdf", "panda_link0", "ball_link").params()
    probe0 = np.array([ball[f"ball_joint.origin.{c}"] for c in "xyz"])

    def block(where: str) -> Any:
        d = read_socket_files(folder / where, angle_unit="rad")
        return ArtifactMeasurement(d.q, d.placement, d.socket,
                                   ArtifactGeometry.two_socket(0.050, length_std=1e-4),
                                   Probe.vector(probe0, estimate=True), "eliminate", "ball",
                                   point_std=5e-5)

    train, h = block("front"), block("left")
    flow = run_flow(robot, [train], [h])
    res = flow.result
    probe = np.array([res.params[f"ball.probe.{c}"] for c in "xyz"])
    sites = h.sites
    keys = [f"{a}/{b}" for a, b in zip(sites.placement, sites.socket, strict=True)]
    site_of = np.asarray(sites.index)

    def spread(rob: Any, tip: np.ndarray) -> np.ndarray:
        """Each seating's distance to the mean of its socket's seatings [m]."""
        T = rob.fk(h.q)
        p = T[:, :3, 3] + T[:, :3, :3] @ tip
        out = np.zeros(len(p))
        for k in range(len(keys)):
            m = site_of == k
            out[m] = np.linalg.norm(p[m] - p[m].mean(axis=0), axis=1)
        return out

    pred = predict(flow.accuracy, res.robot, h.q, point=probe)
    try:
        from kincal.identify.accuracy import predict_spread
    except ImportError:         # kincal before predict_spread: the TCP's error in the base frame
        spread_pred = pred.predicted_m
    else:
        spread_pred = predict_spread(flow.accuracy, res.robot, h.q, site_of)
    return [row_of("Panda two-socket", "placement front -> left (spread about the socket)",
                   len(train.q), spread(robot, probe0), spread(res.robot, probe),
                   spread_pred, pred.outside, flow)]


def _ur10_block(path: Path, every: int) -> PositionMeasurement:
    with open(path, newline="") as f:
        rows = list(csv.reader(f, delimiter=";"))
    head, body = rows[0], rows[1:][::every]

    def col(name: str) -> np.ndarray:
        i = head.index(name)
        return np.array([float(r[i].replace(",", ".")) for r in body])

    joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
              "wrist_2_joint", "wrist_3_joint"]
    q = np.stack([col(j) for j in joints], axis=1)
    y = np.stack([col(f"measurement_{c}") for c in "xyz"], axis=1) * 1e-3
    s = np.sqrt(np.mean(np.stack([col(f"measurement_std_{c}") for c in "xyz"]) ** 2,
                        axis=0)) * 1e-3
    return PositionMeasurement(q, y, np.maximum(s, 1e-6), "tracker")


def ur10() -> list[dict[str, Any]]:
    robot = load_serial_robot("ur10")
    folder = DATA / "ipa_ur10"
    b = _ur10_block(folder / "Series_B" / "measurements_joint_configurations.csv", 4)
    c = _ur10_block(folder / "Series_C" / "measurements_random_poses.csv", 4)
    return [position_split("UR10 (IPA)", "series B (joint grid) -> series C (random poses)",
                           robot, b, c)]


def rosi() -> list[dict[str, Any]]:
    """The two-axis positioner: the target's origin in the camera frame (position only);
    train on ``|j1| <= 15 deg`` (j2 over its whole turn), hold out the rest."""
    import yaml

    from kincal.robots.dh import DHLink, from_dh

    doc = yaml.safe_load((DATA / "rosi_positioner" / "measurements.yaml").read_text())
    rows = [doc[k] for k in sorted(doc)]
    q = np.array([r["target_joints"] for r in rows], dtype=float)
    y = np.array([[r["pose"][c] for c in "xyz"] for r in rows], dtype=float)
    # classical DH [d, theta, r, alpha] = [0, 0, 0, -90 deg], [-0.475 m, -90 deg, 0, 0];
    # base Trans(2.2, 0, 1.6) Rx(90 deg) (the source example's nominal)
    robot = from_dh([DHLink(a=0.0, d=0.0, alpha=-np.pi / 2, theta_offset=0.0, name="j1"),
                     DHLink(a=0.0, d=-0.475, alpha=0.0, theta_offset=-np.pi / 2, name="j2")],
                    name="rosi_positioner", base=(2.2, 0.0, 1.6, 0.0, 0.0, np.pi / 2))
    block = PositionMeasurement(q, y, 1e-3, "camera")
    inner = np.abs(q[:, 0]) <= np.radians(15.0) + 1e-6
    return [position_split("ROSI two-axis positioner", "abs(j1) <= 15 deg -> the rest",
                           robot, block.subset(np.flatnonzero(inner)),
                           block.subset(np.flatnonzero(~inner)))]


def simulated(half_deg: float, seeds: int = 8, cyclic_deg: float = 0.0
              ) -> list[dict[str, Any]]:
    """PUMA 560 with known errors: 60 training poses in a +-``half_deg`` box about the
    middle of the joint ranges, held out 30 inside it and 200 in +-90 deg (pooled over
    ``seeds`` robots: each RMS is over all their poses).  ``cyclic_deg``: the truth also
    has a joint error ``cyclic_deg sin(2 q_j + j)`` the model does not have."""
    from types import SimpleNamespace

    robot = load_serial_robot("puma560")
    lim = robot.joint_limits
    c = 0.5 * (lim[:, 0] + lim[:, 1])
    big = np.minimum(0.8 * 0.5 * (lim[:, 1] - lim[:, 0]), np.radians(90.0))
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("nom", "cal", "pred", "out")}
    flows: list[Any] = []
    worse = 0
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        true = perturb_robot(robot, rng)
        small = np.radians(half_deg)
        qt = c + rng.uniform(-1, 1, (60, robot.n)) * small
        qv = np.vstack([c + rng.uniform(-1, 1, (30, robot.n)) * small,
                        c + rng.uniform(-1, 1, (200, robot.n)) * big])

        def measured(q: np.ndarray, rng: Any = rng, true: Any = true) -> PositionMeasurement:
            dq = np.radians(cyclic_deg) * np.sin(2 * q + np.arange(robot.n))
            b = simulate_positions(true, q + dq, rng, 1e-5, [1.5, 0.3, 0.2, 0.4, 0.1, -0.2],
                                   [0.003, -0.004, 0.06], name="tracker")
            return PositionMeasurement(q, b.positions, 1e-5, "tracker")

        flow = run_flow(robot, [measured(qt)], [measured(qv)], validation_frames="training",
                        max_iter=400)
        (f,) = flow.heldout
        nominal = np.asarray(f.before["position_m"]).reshape(len(qv), -1)[:, 0]
        out = f.prediction.outside
        worse += _rms(f.point_errors[out]) > _rms(nominal[out]) + 1e-4
        parts["nom"].append(nominal)
        parts["cal"].append(f.point_errors)
        parts["pred"].append(f.prediction.predicted_m)
        parts["out"].append(out)
        flows.append(flow)
    pooled = SimpleNamespace(trusted=all(fl.trusted for fl in flows), flows=flows,
                             warnings=sorted({w for fl in flows for w in fl.warnings}))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    what = f" + cyclic joint error {cyclic_deg:g} deg" if cyclic_deg else ""
    return [row_of("simulated PUMA 560" + what, f"+-{half_deg:g} deg box -> +-90 deg "
                   f"({seeds} robots; {worse} worse than nominal outside by > 0.1 mm)", 60,
                   cat["nom"], cat["cal"], cat["pred"], cat["out"].astype(bool), pooled)]


CASES: dict[str, Callable[[], list[dict[str, Any]]]] = {
    "motoman": motoman, "tiago": tiago, "panda": panda, "ur10": ur10, "rosi": rosi,
    "sim": lambda: simulated(1.0) + simulated(3.0) + simulated(10.0, 6, 0.02)}


def table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown table: measured and predicted RMS [mm], inside and outside."""
    def mm(x: float) -> str:
        return "-" if not np.isfinite(x) else f"{x * 1e3:.3g}"

    def ratio(p: float, m: float) -> str:
        return "-" if not (np.isfinite(p) and np.isfinite(m) and m > 0) else f"{p / m:.2f}"

    lines = ["| data | split | train | held in / out | nominal in / out [mm] | "
             "calibrated in / out [mm] | predicted in / out [mm] | predicted / measured "
             "in / out | trusted | warns before use |", "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r['data']} | {r['split']} | {r['train']} | {r['n_in']} / {r['n_out']} | "
            f"{mm(r['nominal_in'])} / {mm(r['nominal_out'])} | {mm(r['calibrated_in'])} / "
            f"{mm(r['calibrated_out'])} | {mm(r['predicted_in'])} / {mm(r['predicted_out'])} | "
            f"{ratio(r['predicted_in'], r['calibrated_in'])} / "
            f"{ratio(r['predicted_out'], r['calibrated_out'])} | "
            f"{'yes' if r['trusted'] else 'no'} | {r['extrapolation_warned']} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=",".join(CASES), help="comma-separated: "
                    + ", ".join(CASES))
    ap.add_argument("--json", help="also write the rows here")
    ap.add_argument("--data", help="the shared data folder (default ../shared/data)")
    args = ap.parse_args(argv)
    if args.data:
        globals()["DATA"] = Path(args.data)
    rows: list[dict[str, Any]] = []
    for key in [k.strip() for k in args.only.split(",") if k.strip()]:
        if key not in CASES:
            ap.error(f"unknown case {key!r}")
        t0 = time.perf_counter()
        try:
            got = CASES[key]()
        except FileNotFoundError as exc:
            print(f"{key}: skipped ({exc})", file=sys.stderr)
            continue
        rows += got
        print(f"{key}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    print(table(rows))
    for r in rows:
        for w in sorted({w[:160] + ("..." if len(w) > 160 else "") for w in r["warnings"]
                         if w.startswith("extrapolation:")}):
            print(f"- {r['data']}, {r['split']}: {w}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
