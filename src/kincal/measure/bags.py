"""ROS bags in: the static postures of a recorded session as a kincal measurement file.

A calibration session recorded in a bag has the robot's ``sensor_msgs/JointState`` stream
and an instrument's stream: a tracked point (``geometry_msgs/PointStamped``), a pose
(``geometry_msgs/PoseStamped``) or a transform on ``/tf`` (``PARENT:CHILD``, e.g. a
motion-capture rigid body).  The robot stops at each posture for the measurement and
moves in between, and the instrument may report all the time.

**Static postures.**  A standstill is a maximal run of joint samples in which every
joint's speed ``|q_{k+1} - q_k| / (t_{k+1} - t_k)`` stays below ``still_speed`` [rad/s or
m/s], lasting at least ``still_time`` [s].  Its first and last ``settle`` seconds are cut
(the arm still rings after a stop).  The posture is the mean of the joint samples in what
remains, the measurement the mean of the instrument samples in the same time window
(poses: the chordal mean of the rotations), and its ``sigma`` the standard error of that
mean, ``sqrt(mean per-axis variance / n)``, at least ``sigma_floor``.

A posture is dropped, and the reason reported, when its standstill is too short, when
the instrument has fewer than ``min_samples`` samples in it (a tracker that lost the
reflector), or when the instrument samples spread more than ``max_spread`` (the marker
moved).  Defaults (0.01 rad/s, 1 s, 0.2 s, 3 samples, 1 mm) suit a laser tracker at
10-1000 Hz and a motion-capture system at 100-200 Hz with joint states at 50-1000 Hz.

**Joint states only.**  Without an instrument topic the standstills are found the same
way and each posture is written with its time window (``t0_s``, ``t1_s``: the bag's
time stamps, s since 1970) so it can be joined with an instrument that logs on its own:
take the instrument's samples whose time stamps fall inside ``[t0_s, t1_s]`` (clocks
synchronised, e.g. by NTP/PTP) and average them.

Reading uses ``rosbags`` (pure Python, no ROS install; the ``ros`` extra): ROS 1 ``.bag``
files and ROS 2 bag folders with ``.db3`` or ``.mcap`` storage.  Units: SI inside; the
written file says its units in every column.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import MeasurementFileError
from kincal.measure.instruments.common import project_so3
from kincal.spatial import log_so3, matrix_to_rpy, quat_to_matrix

Array = NDArray[np.float64]

__all__ = ["BagSession", "Posture", "StillOptions", "find_postures", "postures_text",
           "read_bag_streams"]


@dataclass(frozen=True)
class StillOptions:
    """How standstills are found (module docstring); SI units."""

    still_speed: float = 0.01
    still_time: float = 1.0
    settle: float = 0.2
    min_samples: int = 3
    max_spread: float = 1e-3
    sigma_floor: float = 1e-6


@dataclass
class BagSession:
    """The streams of a bag: joint states and instrument samples, times in s."""

    joint_names: list[str]
    joint_t: Array
    joint_q: Array
    meas_t: Array
    meas_p: Array
    meas_R: Array | None
    kind: str                                 # "point" | "pose" | "joints" (no instrument)
    source: str
    notes: list[str] = field(default_factory=list)


@dataclass
class Posture:
    """One static posture: mean joints, mean measurement, its sigma and time window."""

    t0: float
    t1: float
    q: Array
    p: Array
    R: Array | None
    sigma: float
    sigma_rot: float
    n: int


def _stamp(msg: object, fallback_ns: int) -> float:
    header = getattr(msg, "header", None)
    st = getattr(header, "stamp", None)
    if st is not None:
        t = float(st.sec) + 1e-9 * float(st.nanosec)
        if t > 0:
            return t
    return fallback_ns * 1e-9


#: The message types each stream accepts (ROS 2 spelling; ROS 1's ``pkg/Type`` too).
_TYPES = {"joints": ("sensor_msgs/msg/JointState",),
          "point": ("geometry_msgs/msg/PointStamped",),
          "pose": ("geometry_msgs/msg/PoseStamped",),
          "tf": ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")}


def _check_type(topic: str, msgtype: str, what: str, option: str, path: str) -> None:
    want = _TYPES[what]
    if msgtype.replace("/msg/", "/") not in [w.replace("/msg/", "/") for w in want]:
        raise MeasurementFileError(f"{option} {topic}: its messages are {msgtype}, expected "
                                   f"{' or '.join(want)}", source=path)


def read_bag_streams(path: str, joints_topic: str, point: str | None = None,
                     pose: str | None = None, tf: str | None = None,
                     joint_names: Sequence[str] | None = None) -> BagSession:
    """Read the joint states and one instrument stream of a bag (module docstring).

    At most one of ``point`` (topic), ``pose`` (topic) or ``tf`` (``"PARENT:CHILD"``);
    none: joint states only (``kind == "joints"``).
    ``joint_names`` keeps only those joints (default: every joint of the first message).
    Errors name the bag and the topic.
    """
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:                                  # pragma: no cover
        raise MeasurementFileError("reading ROS bags needs the 'ros' extra: pip install "
                                   "'kincal[ros]'", source=path) from None
    chosen = [x for x in (point, pose, tf) if x]
    if len(chosen) > 1:
        raise MeasurementFileError("give at most one of --point TOPIC, --pose TOPIC, "
                                   "--tf PARENT:CHILD", source=path)
    p = Path(path)
    if not p.exists():
        raise MeasurementFileError("no such bag", source=path)
    parent = child = ""
    if tf:
        if ":" not in tf:
            raise MeasurementFileError(f"--tf {tf!r}: give PARENT:CHILD frame names",
                                       source=path)
        parent, child = tf.split(":", 1)
    meas_topic = point or pose or ("/tf" if tf else None)
    kind = "point" if point else "pose" if (pose or tf) else "joints"
    jt: list[float] = []
    jq: list[list[float]] = []
    mt: list[float] = []
    mp: list[list[float]] = []
    mR: list[Array] = []
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:                            # noqa: BLE001 - rosbags' own errors
        raise MeasurementFileError(f"not a readable ROS bag: damaged, unindexed (still being "
                                   f"recorded?) or not a bag ({_short(exc)}); 'rosbag "
                                   "reindex' / 'ros2 bag reindex' may repair it",
                                   source=path) from None
    try:
        names = _read_messages(reader, path, joints_topic, meas_topic, kind, parent, child,
                               joint_names, jt, jq, mt, mp, mR)
    except MeasurementFileError:
        raise
    except Exception as exc:                            # noqa: BLE001 - a damaged chunk
        raise MeasurementFileError(f"damaged ROS bag: reading its messages failed "
                                   f"({_short(exc)}); 'rosbag reindex' / 'ros2 bag reindex' "
                                   "may repair it", source=path) from None
    finally:
        reader.close()
    if not jt:
        raise MeasurementFileError(f"{joints_topic}: no joint states", source=path)
    if not mt and kind != "joints":
        what = f"transform {parent} -> {child}" if tf else f"messages on {meas_topic}"
        raise MeasurementFileError(f"no {what}", source=path)
    jt_a, mt_a = np.array(jt), np.array(mt)
    js, ms = np.argsort(jt_a, kind="stable"), np.argsort(mt_a, kind="stable")
    mp_a = np.array(mp).reshape(-1, 3)
    return BagSession(list(names or []), jt_a[js], np.array(jq)[js], mt_a[ms],
                      mp_a[ms], (np.array(mR)[ms] if kind == "pose" else None),
                      kind, path)


def _short(exc: Exception) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:120]


def _read_messages(reader: Any, path: str, joints_topic: str, meas_topic: str | None,
                   kind: str, parent: str, child: str, joint_names: Sequence[str] | None,
                   jt: list[float], jq: list[list[float]], mt: list[float],
                   mp: list[list[float]], mR: list[Array]) -> list[str] | None:
    """Fill the sample lists from an open bag; the joint names kept."""
    tf = bool(parent)
    names: list[str] | None = None
    topics = {c.topic: c for c in reader.connections}
    wanted = [(joints_topic, "joints", "--joints")]
    if meas_topic is not None:
        wanted.append((meas_topic, "tf" if tf else kind, "--tf" if tf else f"--{kind}"))
    for topic, what, option in wanted:
        if topic not in topics:
            raise MeasurementFileError(f"no topic {topic!r} (topics: "
                                       f"{', '.join(sorted(topics))})", source=path)
        for c in reader.connections:
            if c.topic == topic:
                _check_type(topic, c.msgtype, what, option, path)
    conns = [c for c in reader.connections if c.topic in (joints_topic, meas_topic)]
    for conn, t_ns, raw in reader.messages(connections=conns):
        msg: Any = reader.deserialize(raw, conn.msgtype)    # a ROS message (typed by rosbags
        # per message type at run time)
        if conn.topic == joints_topic:
            if names is None:
                names = list(msg.name)
                keep = list(joint_names) if joint_names else names
                missing = [n for n in keep if n not in names]
                if missing:
                    raise MeasurementFileError(f"{joints_topic}: no joint "
                                               f"{', '.join(missing)} (joints: "
                                               f"{', '.join(names)})", source=path)
                names = keep
            order = {n: i for i, n in enumerate(msg.name)}
            try:
                jq.append([float(msg.position[order[n]]) for n in names])
            except (KeyError, IndexError):
                continue                            # a message for other joints
            jt.append(_stamp(msg, t_ns))
        elif tf:
            for tr in msg.transforms:
                if tr.header.frame_id.lstrip("/") == parent.lstrip("/") and \
                        tr.child_frame_id.lstrip("/") == child.lstrip("/"):
                    v, r = tr.transform.translation, tr.transform.rotation
                    mt.append(_stamp(tr, t_ns))
                    mp.append([v.x, v.y, v.z])
                    mR.append(quat_to_matrix([r.w, r.x, r.y, r.z]))
        elif kind == "pose":
            ps = msg.pose
            mt.append(_stamp(msg, t_ns))
            mp.append([ps.position.x, ps.position.y, ps.position.z])
            o = ps.orientation
            mR.append(quat_to_matrix([o.w, o.x, o.y, o.z]))
        else:
            mt.append(_stamp(msg, t_ns))
            mp.append([msg.point.x, msg.point.y, msg.point.z])
    return names


def _still_runs(t: Array, q: Array, speed: float) -> list[tuple[int, int]]:
    """Index ranges [i, j] of maximal runs of samples whose neighbouring speeds are low."""
    if len(t) < 2:
        return []
    dt = np.diff(t)
    v = np.max(np.abs(np.diff(q, axis=0)), axis=1) / np.where(dt > 0, dt, np.inf)
    slow = v < speed
    runs = []
    i = None
    for k, s in enumerate(slow):
        if s and i is None:
            i = k
        elif not s and i is not None:
            runs.append((i, k))
            i = None
    if i is not None:
        runs.append((i, len(slow)))
    return runs


def find_postures(s: BagSession, opt: StillOptions = StillOptions()
                  ) -> tuple[list[Posture], list[str]]:
    """The static postures of a session and one line per dropped standstill."""
    postures: list[Posture] = []
    dropped: list[str] = []
    for i, j in _still_runs(s.joint_t, s.joint_q, opt.still_speed):
        t0, t1 = float(s.joint_t[i]), float(s.joint_t[j])
        where = f"standstill {t0 - s.joint_t[0]:.2f}-{t1 - s.joint_t[0]:.2f} s"
        if t1 - t0 < opt.still_time:
            if t1 - t0 >= 0.25 * opt.still_time:
                dropped.append(f"{where}: shorter than {opt.still_time:g} s")
            continue
        a, b = t0 + opt.settle, t1 - opt.settle
        jsel = (s.joint_t >= a) & (s.joint_t <= b)
        if s.kind == "joints":                  # no instrument: the posture and its window
            postures.append(Posture(a, b, s.joint_q[jsel].mean(axis=0), np.full(3, np.nan),
                                    None, math.nan, math.nan, int(jsel.sum())))
            continue
        msel = (s.meas_t >= a) & (s.meas_t <= b)
        n = int(msel.sum())
        if n < opt.min_samples:
            dropped.append(f"{where}: {n} instrument sample{'s' if n != 1 else ''} "
                           f"(at least {opt.min_samples} needed; marker lost?)")
            continue
        p = s.meas_p[msel]
        spread = float(np.max(np.linalg.norm(p - p.mean(axis=0), axis=1)))
        if spread > opt.max_spread:
            dropped.append(f"{where}: the instrument samples spread {spread * 1e3:.3f} mm "
                           f"(more than {opt.max_spread * 1e3:g} mm: the marker moved)")
            continue
        sigma = max(math.sqrt(float(np.mean(p.var(axis=0, ddof=1))) / n), opt.sigma_floor)
        R = None
        sigma_rot = math.nan
        if s.meas_R is not None:
            Rs = s.meas_R[msel]
            R = project_so3(Rs.mean(axis=0))
            w = log_so3(Rs @ R.T)
            sigma_rot = max(math.sqrt(float(np.mean(w.var(axis=0, ddof=1))) / n), 1e-7)
        postures.append(Posture(a, b, s.joint_q[jsel].mean(axis=0), p.mean(axis=0), R,
                                sigma, sigma_rot, n))
    return postures, dropped


def postures_text(s: BagSession, postures: Sequence[Posture]) -> str:
    """The standstill postures of a joints-only bag: ``t0_s, t1_s`` (the bag's time stamps,
    s) and the mean joints [rad], one row per posture, to be joined by time with an
    instrument's own log (module docstring)."""
    head = ["t0_s", "t1_s"] + [f"{n}_rad" for n in s.joint_names]
    lines = [f"# kincal standstill postures from {Path(s.source).name} (kincal import bag, "
             "joint states only): join each row with the instrument samples whose time "
             "stamps fall in [t0_s, t1_s]", ",".join(head)]
    for ps in postures:
        lines.append(",".join([f"{ps.t0:.6f}", f"{ps.t1:.6f}"]
                              + [repr(float(v)) for v in ps.q]))
    return "\n".join(lines) + "\n"


def measurement_text(s: BagSession, postures: Sequence[Posture], name: str = "bag") -> str:
    """The kincal measurement CSV of the postures: joints in rad (m for prismatic joints is
    not known from a JointState: all joints are written in rad), x, y, z in mm, rx, ry, rz
    (roll-pitch-yaw) in deg for poses, sigma per posture."""
    pose = s.kind == "pose"
    tag = "pose" if pose else "position"
    head = [f"{n}_rad" for n in s.joint_names] + ["x_mm", "y_mm", "z_mm"]
    if pose:
        head += ["rx_deg", "ry_deg", "rz_deg"]
    head += ["sigma_mm"] + (["sigma_rot_deg"] if pose else [])
    lines = [f"# kincal measurements: instrument={tag}; name={name}",
             f"# {len(postures)} static postures from {Path(s.source).name} "
             "(kincal import bag)", ",".join(head)]
    for ps in postures:
        row = [repr(float(v)) for v in ps.q] + [f"{v * 1e3:.6f}" for v in ps.p]
        if pose and ps.R is not None:
            row += [f"{math.degrees(v):.8f}" for v in matrix_to_rpy(ps.R)]
        row += [f"{ps.sigma * 1e3:.6f}"]
        if pose:
            row += [f"{math.degrees(ps.sigma_rot):.8f}"]
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"
