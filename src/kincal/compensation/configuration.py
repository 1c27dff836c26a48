"""Robot configurations as controllers write them: KUKA S/T, ABB confdata, FANUC CONFIG.

A Cartesian target of a 6R arm has up to 8 joint solutions, more when an axis can
turn past 360 deg.  A program says which one it means; this module reads that
statement as a :class:`Configuration` (three branch signs and an interval per axis)
and picks the matching joint solution among the closed-form ones
(:func:`kincal.motion.ik_wrist.ik_spherical_wrist`).

The three branch signs come from :func:`kincal.motion.ik_wrist.arm_indicators`,
normalised so that ``+1`` is the side the arm is on in the vendor's reference posture
(``shoulder``: wrist centre in front of axis 1; ``elbow``: wrist centre on the same
side of the line through axes 2 and 3 as in the reference posture); the wrist sign is
the sign of controller axis 5.

* KUKA (``S``, ``T`` of ``E6POS``/``POS``): S bit 0 set = wrist centre behind axis 1
  (overhead area), bit 1 set = elbow as at HOME (``A2 = -90, A3 = +90 deg``), bit 2 set =
  ``A5 < 0``; T bit k set = axis k+1 negative (KUKA System Software manual, "Status and
  Turn").
* ABB (``confdata [cf1, cf4, cf6, cfx]``): cf1, cf4, cf6 are the quadrants of axes 1, 4,
  6 (quadrant k = ``[90 k, 90 (k + 1))`` deg); cfx = 4 (wrist centre behind axis 1) + 2
  (behind the lower arm) + 1 (axis 5 negative), the reference being the calibration
  position (RAPID reference manual, ``confdata``).
* FANUC (``CONFIG : 'N U T, t1, t4, t6'``): F/N = wrist flipped / not (N: ``J5 <= 0``,
  the tool-down posture of most programs), U/D = elbow up / down (U: as at the zero
  posture), T/B = front / back of J1; turn numbers of J1, J4, J6: turn t covers
  ``(-180 + 360 t, 180 + 360 t]`` deg.

Units: intervals in the controller's axis units converted to rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.motion.ik_wrist import arm_indicators
from kincal.robots.chain import Robot
from kincal.robots.controller import ControllerMap

Array = NDArray[np.float64]

#: Reference postures (controller axes, deg) in which each vendor's shoulder and elbow
#: signs are +1.
REFERENCE_AXES_DEG = {"kuka": (0.0, -90.0, 90.0, 0.0, 0.0, 0.0),
                      "abb": (0.0,) * 6, "fanuc": (0.0,) * 6}
_D = math.pi / 180.0


@dataclass(frozen=True)
class Configuration:
    """The branch a program asks for.

    Attributes:
        shoulder, elbow, wrist: +1 / -1, or 0 when the program leaves it free.
        intervals: per controller axis (0-based), ``(lo, hi)`` [rad] it must lie in.
        text: the configuration as the program wrote it (for messages).
    """

    shoulder: int = 0
    elbow: int = 0
    wrist: int = 0
    intervals: dict[int, tuple[float, float]] = field(default_factory=dict)
    text: str = ""


def kuka_configuration(s: int | None, t: int | None) -> Configuration:
    """:class:`Configuration` from KUKA's Status and Turn (None: not given)."""
    conf = Configuration(text=f"S {s} T {t}")
    sh = el = wr = 0
    if s is not None:
        sh = -1 if s & 1 else 1
        el = 1 if s & 2 else -1
        wr = -1 if s & 4 else 1
    iv: dict[int, tuple[float, float]] = {}
    if t is not None:
        for k in range(6):
            iv[k] = (-2 * math.pi, 0.0) if t >> k & 1 else (0.0, 2 * math.pi)
        wr = -1 if t >> 4 & 1 else 1 if s is None else wr
    return Configuration(sh, el, wr, iv, conf.text)


def abb_configuration(cf1: int, cf4: int, cf6: int, cfx: int) -> Configuration:
    """:class:`Configuration` from ABB's confdata."""
    iv = {k: (cf * math.pi / 2, (cf + 1) * math.pi / 2) for k, cf in ((0, cf1), (3, cf4),
                                                                      (5, cf6))}
    if not 0 <= cfx <= 7:
        return Configuration(0, 0, 0, iv, f"[{cf1},{cf4},{cf6},{cfx}]")
    return Configuration(-1 if cfx & 4 else 1, -1 if cfx & 2 else 1, -1 if cfx & 1 else 1,
                         iv, f"[{cf1},{cf4},{cf6},{cfx}]")


def fanuc_configuration(flags: str, turns: tuple[int, int, int]) -> Configuration:
    """:class:`Configuration` from FANUC's ``'N U T'`` flags and J1, J4, J6 turn numbers."""
    f = flags.upper().split()
    wr = {"N": -1, "F": 1}.get(next((x for x in f if x in "NF"), ""), 0)
    el = {"U": 1, "D": -1}.get(next((x for x in f if x in "UD"), ""), 0)
    sh = {"T": 1, "B": -1}.get(next((x for x in f if x in "TB"), ""), 0)
    iv = {k: ((-180 + 360 * t) * _D, (180 + 360 * t) * _D) for k, t in zip((0, 3, 5), turns,
                                                                           strict=True)}
    return Configuration(sh, el, wr, iv, f"'{flags}, {', '.join(map(str, turns))}'")


@dataclass(frozen=True)
class Configurator:
    """Branch signs of a robot with a controller map, normalised by the vendor's reference."""

    robot: Robot
    cmap: ControllerMap
    norm: Array

    @classmethod
    def of(cls, robot: Robot, cmap: ControllerMap) -> Configurator:
        ref = REFERENCE_AXES_DEG.get(cmap.vendor)
        if ref is None:
            raise KincalError(f"robot {robot.name!r}: no configuration rules for controller "
                              f"vendor {cmap.vendor!r}")
        q_ref = cmap.to_model(np.array(ref) * (1.0 if cmap.unit == "deg" else _D))
        ind = arm_indicators(robot, q_ref)[0]
        return cls(robot, cmap, np.sign(ind[:2]))

    def signs(self, q: Array) -> Array:
        """(N, 3) shoulder, elbow, wrist signs at model joints q (N, 6) [rad]."""
        ind = arm_indicators(self.robot, q)
        a5 = self.cmap.to_axes(q)[:, 4]
        return np.stack([np.sign(ind[:, 0]) * self.norm[0], np.sign(ind[:, 1]) * self.norm[1],
                         np.where(a5 < 0, -1.0, 1.0)], 1)

    def margins(self, q: Array) -> Array:
        """(N, 3) distances to the three singularities: ``|a1 + u|`` [m], ``|Y|`` [m]
        (``|Y| / |(a3, e)|`` is the sine of the elbow's angle from stretched or folded),
        ``|sin theta5|`` (:func:`~kincal.motion.ik_wrist.arm_indicators`)."""
        return np.abs(arm_indicators(self.robot, q))

    def select(self, candidates: Array, valid: NDArray[np.bool_],
               confs: list[Configuration | None]) -> tuple[Array, NDArray[np.bool_]]:
        """Pick, per target, the candidate solution with the asked configuration.

        Args:
            candidates: (N, B, 6) model joint values [rad] (e.g. the 8 closed-form branches).
            valid: (N, B) which candidates exist.
            confs: N configurations (None: free; the first valid candidate is taken).

        Each candidate's axes with an interval are first moved by whole turns into it;
        a candidate qualifies when its three signs match, every interval holds and the
        joints are inside the limits.  Returns ``(q (N, 6), found (N,))``.
        """
        N, B, n = candidates.shape
        want = np.zeros((N, 3))
        lo = np.full((N, n), np.nan)
        hi = np.full((N, n), np.nan)
        for i, c in enumerate(confs):
            if c is None:
                continue
            want[i] = (c.shoulder, c.elbow, c.wrist)
            for k, (a, b) in c.intervals.items():
                lo[i, k], hi[i, k] = a, b
        flat = np.nan_to_num(candidates.reshape(N * B, n))
        ax = self.cmap.to_axes(flat).reshape(N, B, n) * self.cmap.scale
        has = ~np.isnan(lo)[:, None, :]
        lo_b = np.broadcast_to(lo[:, None, :], ax.shape)
        width = 2 * math.pi
        tol = 1e-9                            # a value on a boundary belongs to either side
        lo0 = np.nan_to_num(lo_b)
        shifted = np.where(has, lo0 - tol + np.mod(ax - lo0 + tol, width), ax)
        if self.cmap.vendor == "fanuc":       # FANUC turns are (lo, hi]: lo itself is hi - 2 pi
            shifted = np.where(has & np.isclose(shifted, lo_b, atol=1e-12), shifted + width,
                               shifted)
        inside_iv = np.where(has, (shifted >= lo_b - 1e-9)
                             & (shifted <= np.broadcast_to(hi[:, None, :], ax.shape) + 1e-9),
                             True).all(axis=2)
        q = self.cmap.to_model(shifted.reshape(N * B, n) / self.cmap.scale)
        signs = self.signs(q).reshape(N, B, 3)
        sign_ok = np.all((want[:, None, :] == 0) | (signs == want[:, None, :]), axis=2)
        lim = self.robot.joint_limits
        q = q.reshape(N, B, n)
        in_lim = np.all((q >= lim[:, 0] - 1e-9) & (q <= lim[:, 1] + 1e-9), axis=2)
        ok = valid & inside_iv & sign_ok & in_lim
        first = np.argmax(ok, axis=1)
        found = ok.any(axis=1)
        return q[np.arange(N), first], found

    def has(self, q: Array, conf: Configuration | None) -> NDArray[np.bool_]:
        """(N,) whether the joint vectors q (N, 6) [rad] themselves have configuration
        ``conf`` (signs and intervals; no turn is moved)."""
        if conf is None:
            return np.ones(len(q), bool)
        s = self.signs(q)
        ok = np.ones(len(q), bool)
        for k, want in enumerate((conf.shoulder, conf.elbow, conf.wrist)):
            if want:
                ok &= s[:, k] == want
        ax = self.cmap.to_axes(q) * self.cmap.scale
        for k, (lo, hi) in conf.intervals.items():
            ok &= (ax[:, k] >= lo - 1e-9) & (ax[:, k] <= hi + 1e-9)
        return ok


#: The straight joint path from the nominal to the corrected joints is checked at this many
#: points (ends included).
CONTINUATION_SAMPLES = 17
#: Along that path the flange may leave the nominal target by at most this factor times the
#: correction plus :data:`CONTINUATION_SLACK` (position [m], rotation [rad]): a continuation
#: moves it nearly straight (second-order terms ~ |dq|^2 x arm length, nanometres for the
#: sub-degree corrections of a calibration).
CONTINUATION_FACTOR = 1.5
CONTINUATION_SLACK = (1e-4, 1e-3)


def jacobian_signature(J: Array) -> Array:
    """The orientation of a full-rank Jacobian ``J`` (N, 6, m), m = 6 or 7: (N, 1) ``det J``
    for m = 6; for m = 7 the (N, 7) vector of signed maximal minors ``c_k = (-1)^k det J_k``
    (``J_k``: column k removed), which spans the null space of J (``J c = 0``, Cramer).  Both
    vanish exactly where J loses rank and change sign (``c`` turns into ``-c``) where the arm
    passes through such a singularity; elsewhere they vary continuously."""
    N, _, m = J.shape
    if m == 6:
        return np.asarray(np.linalg.det(J), float)[:, None]
    if m != 7:
        raise KincalError(f"jacobian_signature: 6 or 7 free joints, not {m}")
    cols = [np.linalg.det(np.delete(J, k, axis=2)) * (-1.0) ** k for k in range(m)]
    return np.stack(cols, axis=1)


def continuation_problems(robot: Robot, q_from: Array, q_to: Array,
                          free: NDArray[np.bool_] | None = None,
                          samples: int = CONTINUATION_SAMPLES) -> list[str]:
    """Whether the joints ``q_to`` (N, n) [rad] are the continuous continuation of ``q_from``
    on any serial chain (no closed form needed): ``""`` where they are, else the reason.

    Along the straight joint path ``q(s) = q_from + s (q_to - q_from)``, s in [0, 1]:

    1. the flange ``T(s) = f(q(s))`` stays near the target: ``|p(s) - p(0)| <= 1.5 |p(1) -
       p(0)| + 0.1 mm`` and ``angle(R(s) R(0)^T) <= 1.5 angle(R(1) R(0)^T) + 1e-3 rad`` (a
       solution on another branch reaches the same pose through a far-away path);
    2. no singularity is crossed: the Jacobian's signature (:func:`jacobian_signature` of
       the ``free`` columns, default all) keeps its sign from sample to sample; where a
       chain has another number of free joints only test 1 is made.
    """
    q_from = np.atleast_2d(np.asarray(q_from, float))
    q_to = np.atleast_2d(np.asarray(q_to, float))
    N, n = q_from.shape
    s = np.linspace(0.0, 1.0, samples)
    path = q_from[:, None, :] + s[None, :, None] * (q_to - q_from)[:, None, :]
    flat = path.reshape(N * samples, n)
    T = robot.fk(flat).reshape(N, samples, 4, 4)
    dp = np.linalg.norm(T[:, :, :3, 3] - T[:, :1, :3, 3], axis=2)
    rel = np.einsum("nsij,nkj->nsik", T[:, :, :3, :3], T[:, 0, :3, :3])
    dr = np.arccos(np.clip((np.trace(rel, axis1=2, axis2=3) - 1.0) / 2.0, -1.0, 1.0))
    far_p = dp.max(axis=1) > CONTINUATION_FACTOR * dp[:, -1] + CONTINUATION_SLACK[0]
    far_r = dr.max(axis=1) > CONTINUATION_FACTOR * dr[:, -1] + CONTINUATION_SLACK[1]
    cols = np.ones(n, bool) if free is None else np.asarray(free, bool)
    flip = np.zeros(N, bool)
    if int(cols.sum()) in (6, 7):
        J = robot.jacobian(flat)[:, :, cols]
        sig = jacobian_signature(J).reshape(N, samples, -1)
        flip = np.any(np.sum(sig[:, 1:] * sig[:, :-1], axis=2) < 0.0, axis=1)
    out = [""] * N
    for i in range(N):
        if flip[i]:
            out[i] = ("configuration changed: the corrected joints lie across a singularity "
                      "of the arm (the Jacobian's minors change sign between the nominal and "
                      "the corrected joints)")
        elif far_p[i] or far_r[i]:
            out[i] = (f"configuration changed: the corrected joints are on another branch "
                      f"(on the way from the nominal joints the flange leaves the target by "
                      f"{dp[i].max() * 1e3:.3g} mm / {math.degrees(dr[i].max()):.3g} deg "
                      f"for a {dp[i, -1] * 1e3:.3g} mm / {math.degrees(dr[i, -1]):.3g} deg "
                      "correction)")
    return out
