"""Drift: did a robot change between its last two calibrations?

For a robot's previous calibration ``a`` and latest ``b`` (two session dates), over the
robot parameters estimated in both (the instruments' frames move between sessions and
are not compared):

* the change ``delta = b - a`` has, for a robot that did not change, the covariance

      C = C_a + C_b + w T,    w = 1 / m_a + 1 / m_b,

  ``C_a``, ``C_b`` the two calibrations' covariances (their measurement noise), ``T``
  the placement-to-placement reproducibility covariance: what the unmodelled errors put
  into the parameters differently at each placement of the artifact or set-up of the
  instrument, averaged over the ``m`` placements (training files) of each session
  (:mod:`kincal.fleet.reproducibility`).  ``T`` is estimated across the fleet by the
  method of moments, ``T = sum_r (delta_r delta_r^T - V_r) / sum_r w_r`` made positive
  semi-definite, over the other robots ``r`` of the same model with two sessions
  (``V_r = C_a + C_b`` of robot ``r``), leaving the robot under test out; ``nu = n - 1``
  pairs stand behind it.  Robots that did drift would pass for session-to-session error:
  the pairs these tests flag with the current estimate leave it, twice
  (:func:`fleet_reproducibility`).  Without two other robots of the model, or with
  ``reproducibility=False``, ``T = 0`` (the calibrations' own covariances alone:
  placements or set-ups that differ between sessions then raise false alarms);
* per parameter, the change in units of its standard error ``s_i = sqrt(C_ii)``:
  ``z_i = delta_i / s_i``;
* the chi-square statistic on the identifiable set, ``chi2 = delta^T C^+ delta`` with
  ``dof = rank(C)``, and its p-value;
* the previous calibration's RMS on the new session's data (the cross-check,
  :func:`kincal.fleet.tasks.crosscheck_session`) beside the new calibration's own.

A robot is flagged when either test rejects "no change" at a family-wise false-alarm
probability ``false_alarm`` per robot (default 0.001), split evenly between the two:
``max |z_i| > z_crit`` with ``z_crit = Phi^-1(1 - false_alarm / (4 p))`` (two-sided,
Bonferroni over ``p`` parameters), or ``P(chi2_dof > chi2) < false_alarm / 2``.  With
``T`` estimated from ``nu`` pairs the covariance is itself uncertain, and the tails
account for it (Welch-Satterthwaite): the standard error ``s_i^2 = v_i + w T_ii`` (the
moment estimate of ``T_ii`` clipped at zero, free of the clipping of the whole matrix) has
``nu_i = nu (s_i^2 / w T_ii)^2`` degrees of freedom (``nu`` when ``T`` dominates,
infinite when ``T_ii = 0``), each ``z_i`` is the normal equivalent of its Student t,
``Phi^-1(F_t,nu_i(delta_i / s_i))``, against the same ``z_crit``; the chi-square becomes
Hotelling's ``chi2 (nu' - dof + 1) / (nu' dof) ~ F(dof, nu' - dof + 1)`` with ``nu' = nu
(tr C / tr wT)^2`` (the chi-square itself when ``T = 0``; with ``nu' <= 2 dof`` the
estimated correlations are too uncertain and only the per-parameter test runs).

The additive ``T`` is one of two models of the placement error; the other, a design
effect, grows it with each session's own variance, ``Var(delta_i) = lambda_i^2 V_ii``
(:mod:`kincal.fleet.reproducibility`, "Two models").  Per parameter the test uses the
model the other robots' changes support (cross-validated log-likelihood ratio beyond
:data:`EVIDENCE`) and otherwise the smaller of the two ``|z_i|``; the chi-square test is
the additive one where the evidence over all parameters supports it, otherwise the
larger of the two p-values (each counts only if both models reject, so the stated
false-alarm rate holds whichever model is true).

The parameters beyond ``z_crit`` are the ones that moved; each gets a sentence
(``d[3] +0.42 mm, 11σ: joint 3 hit something?``).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from kincal.errors import KincalError
from kincal.fleet.reproducibility import (
    PairTerms,
    Reproducibility,
    ReproducibilityPool,
    pair_terms,
    placements,
)
from kincal.fleet.tasks import summary_rms
from kincal.robots.chain import ROLES
from kincal.units import display_scale

__all__ = ["ParameterChange", "Drift", "FleetDrift", "compare", "z_threshold", "fleet_drift",
           "fleet_reproducibility", "joint_test"]


@dataclasses.dataclass
class ParameterChange:
    """One robot parameter between two calibrations (SI: m, rad)."""

    name: str
    unit: str
    role: str
    before: float
    after: float
    sigma: float          # combined standard error of the change
    dof: float = math.inf  # degrees of freedom of sigma (finite: T estimated, Satterthwaite)
    #: the model of placement error ``sigma`` comes from: ``"additive"``, ``"design
    #: effect"``, or ``""`` without one (the calibrations' own covariances alone)
    placement: str = ""
    _z: float | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def change(self) -> float:
        return self.after - self.before

    @property
    def t(self) -> float:
        """``change / sigma``."""
        return self.change / self.sigma if self.sigma > 0 else math.inf * np.sign(self.change)

    @property
    def z(self) -> float:
        """The normal-equivalent of :attr:`t`: ``Phi^-1(F_t,dof(t))`` (``t`` itself when
        ``dof`` is infinite), so that one threshold serves every parameter."""
        if self._z is None:
            self._z = float(_normal_equivalent(np.array([self.t]), np.array([self.dof]))[0])
        return self._z

    def text(self, why: bool = True) -> str:
        """``d[3] +0.4200 mm, 11.0σ: joint 3 hit something?`` (without the guess when
        ``why`` is False)."""
        f, u = display_scale(self.unit)
        text = f"{self.name} {self.change * f:+.4g} {u}, {abs(self.z):.1f}σ"
        return f"{text}: {hint(self.name, self.role)}" if why else text


def _normal_equivalent(t: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """``sign(t) Phi^-1(F_t,dof(|t|))`` element-wise; ``t`` where ``dof`` is infinite."""
    from scipy.special import ndtri, stdtr  # the ufuncs behind scipy.stats' norm and t

    out = np.array(t, dtype=float)
    fin = np.isfinite(dof) & np.isfinite(out) & (out != 0)
    if fin.any():
        tail = stdtr(dof[fin], -np.abs(out[fin]))         # P(T > |t|)
        out[fin] = -np.sign(out[fin]) * ndtri(tail)       # Phi^-1(1 - tail)
    return out


def _joint(name: str) -> str:
    m = re.search(r"\[(\w+)\]", name)
    if m:
        return f"joint {m.group(1)}"
    return f"joint {name.split('.origin')[0].split('.')[0]}"


def hint(name: str, role: str) -> str:
    """What a moved parameter suggests, for people."""
    if role == "offset":
        return f"{_joint(name)}'s encoder zero moved (encoder slipped, replaced or re-mastered?)"
    if role == "base":
        return "the robot's base moved (re-mounted, or its bolts loosened?)"
    if role == "tool":
        return "the tool or flange changed (tool swapped or bent?)"
    return f"{_joint(name)} hit something? (its link geometry changed)"


@dataclasses.dataclass
class Drift:
    """The comparison of a robot's last two calibrations.

    Attributes:
        serial: the robot.
        previous, latest: ``(record id, session date)``.
        changes: every robot parameter estimated in both, ordered by ``|z|``.
        chi2, dof, p_value: the chi-square test on the common identifiable set.
        z_crit: the per-parameter threshold for this robot.
        flagged: either test rejected "no change".
        moved: the changes beyond ``z_crit`` (the largest ``|z|`` ones when only the
            chi-square test rejected).
        rms_latest_m: the latest calibration's training position RMS [m].
        rms_previous_model_m: the previous calibration on the latest data [m] (None
            until the cross-check is stored).
        reproducibility: the session-to-session variance ``T`` in the test (None:
            not estimated, ``T = 0``).
    """

    serial: str
    previous: tuple[int, str]
    latest: tuple[int, str]
    changes: list[ParameterChange]
    chi2: float
    dof: int
    p_value: float
    z_crit: float
    flagged: bool
    moved: list[ParameterChange]
    rms_latest_m: float | None = None
    rms_previous_model_m: float | None = None
    reproducibility: Reproducibility | None = None

    @property
    def z_max(self) -> float:
        return max((abs(c.z) for c in self.changes), default=0.0)

    def notes(self) -> list[str]:
        """Sentences for people: each parameter beyond ``z_crit`` with what it suggests;
        for a robot flagged by the chi-square test alone, the largest changes."""
        if not self.flagged:
            return []
        beyond = [c for c in self.moved if abs(c.z) > self.z_crit]
        if beyond:
            return [c.text() for c in beyond]
        return [f"several parameters changed together (chi-square p = {self.p_value:.2g}; "
                f"none beyond {self.z_crit:.1f}σ alone); largest: "
                + ", ".join(c.text(why=False) for c in self.moved)]

    def to_dict(self) -> dict[str, Any]:
        return {"serial": self.serial, "previous": {"id": self.previous[0],
                                                    "date": self.previous[1]},
                "latest": {"id": self.latest[0], "date": self.latest[1]},
                "flagged": self.flagged, "chi2": self.chi2, "dof": self.dof,
                "p_value": self.p_value, "z_max": self.z_max, "z_crit": self.z_crit,
                "rms_latest_m": self.rms_latest_m,
                "rms_previous_model_m": self.rms_previous_model_m,
                "moved": [c.name for c in self.moved], "notes": self.notes(),
                "reproducibility": (self.reproducibility.to_dict()
                                    if self.reproducibility is not None else None),
                "changes": [{"name": c.name, "unit": c.unit, "role": c.role,
                             "before": c.before, "after": c.after, "change": c.change,
                             "sigma": c.sigma, "z": c.z, "placement": c.placement}
                            for c in self.changes]}


def z_threshold(p: int, false_alarm: float, nu: int | None = None) -> float:
    """``Phi^-1(1 - false_alarm / (4 p))``: the per-parameter two-sided Bonferroni
    threshold holding half of the false-alarm budget over ``p`` parameters; with ``nu``
    (the pairs behind an estimated reproducibility variance) the Student-t quantile
    ``t_nu^-1(1 - false_alarm / (4 p))``."""
    from scipy.special import ndtri, stdtrit  # normal and Student-t quantiles (ufuncs)

    q = false_alarm / (4.0 * max(p, 1))
    return float(-ndtri(q) if nu is None else -stdtrit(nu, q))


def _robot_block(record: Mapping[str, Any]) -> tuple[dict[str, dict[str, Any]], np.ndarray,
                                                     list[str]]:
    params = {p["name"]: p for p in record["parameters"]
              if p["role"] in ROLES and p["estimated"]}
    return params, np.asarray(record["covariance"], dtype=float), list(record["estimated"])


def _satterthwaite(total: Any, estimated: Any, nu: int) -> Any:
    """Degrees of freedom of ``total = known + estimated`` when ``estimated`` comes from
    ``nu`` degrees of freedom (Welch-Satterthwaite): ``nu (total / estimated)^2``,
    infinite when nothing is estimated; element-wise on arrays, a float for numbers."""
    total, estimated = np.asarray(total, dtype=float), np.asarray(estimated, dtype=float)
    some = (estimated > 0) & (total > 0)
    out = np.where(some, nu * (total / np.where(some, estimated, 1.0)) ** 2, math.inf)
    return float(out) if out.ndim == 0 else out


def joint_test(delta: np.ndarray, C: np.ndarray, nu: float | None
               ) -> tuple[float, int, float]:
    """``(chi2, dof, p)``: ``delta^T C^+ delta`` on the identifiable set and its p-value,
    chi-square, or Hotelling's F with ``nu`` pairs behind ``C`` (1 when ``nu <= 2 dof``:
    too few pairs to trust the estimated correlations)."""
    from scipy.special import chdtrc, fdtrc  # chi-square and F upper tails (ufuncs)

    chi2, dof = 0.0, 0
    if delta.size:
        w, V = np.linalg.eigh(C)
        keep = w > w.max() * 1e-12 if w.size and w.max() > 0 else np.zeros(w.size, bool)
        proj = V[:, keep].T @ delta
        chi2, dof = float(np.sum(proj**2 / w[keep])), int(keep.sum())
    if not dof:
        return chi2, dof, 1.0
    if nu is None:
        return chi2, dof, float(chdtrc(dof, chi2))
    if nu > 2 * dof:            # Hotelling: chi2 (nu - dof + 1) / (nu dof) ~ F(dof, nu - dof + 1)
        return chi2, dof, float(fdtrc(dof, nu - dof + 1, chi2 * (nu - dof + 1) / (nu * dof)))
    return chi2, dof, 1.0       # too few pairs for T's correlations: per-parameter test only


def _pair_flagged(pair: PairTerms, repro: Reproducibility | None, false_alarm: float
                  ) -> bool:
    """Would :func:`compare` flag this pair (its change and ``V``) with ``repro``?"""
    names = list(pair.names)
    record: dict[str, Any] = {"parameters": [{"name": n, "unit": "", "role": ROLES[0],
                                              "estimate": v,
                              "estimated": True} for n, v in zip(names, pair.delta,
                                                                 strict=True)],
              "covariance": pair.V, "estimated": names, "serial": pair.serial, "id": 0,
              "date": ""}
    zero = {**record, "parameters": [{**p, "estimate": 0.0} for p in record["parameters"]],
            "covariance": np.zeros_like(pair.V)}
    return compare(zero, record, false_alarm, repro, pair.weight).flagged


def fleet_reproducibility(pairs: Sequence[PairTerms], false_alarm: float = 1e-3,
                          rounds: int = 2) -> dict[str, Reproducibility | None]:
    """Per serial, the session-to-session covariance ``T`` of its model estimated from
    the other robots' pairs (:mod:`kincal.fleet.reproducibility`), robust to the robots
    that did drift: ``rounds`` times, the pairs flagged at ``false_alarm`` with the
    current estimate leave the estimate (a drift would otherwise pass for session-to-
    session error and hide itself and others)."""
    use = list(pairs)
    for _ in range(rounds):
        pool = ReproducibilityPool(use)
        keep = [p for p in use if not _pair_flagged(p, pool.without(p, p.model),
                                                     false_alarm)]
        if len(keep) == len(use):
            break
        use = keep
    pool = ReproducibilityPool(use)
    kept = {p.serial for p in use}
    return {p.serial: pool.without(p if p.serial in kept else None, p.model)
            for p in pairs}


#: Log-likelihood ratio (20:1) from which the other robots' changes are taken to settle
#: which model of placement error holds (below it both are used, the milder verdict wins).
EVIDENCE = math.log(20.0)


def _both_models(delta: np.ndarray, V: np.ndarray, names: Sequence[str],
                 repro: Reproducibility, weight: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                            tuple[float, int, float]]:
    """Per parameter the standard error and degrees of freedom of the model of placement
    error the other robots support (log-likelihood ratio beyond :data:`EVIDENCE`), else of
    the one that finds the change smaller; the additive joint test where the evidence over
    all parameters at once supports it, else the one that rejects less
    (:mod:`kincal.fleet.reproducibility`, "Two models"): ``(sd, dof, z, design, (chi2,
    dof, p))``
    (``z`` the normal equivalents of ``delta / sd``, ``design`` True where the design
    effect gave them).  Additive: ``V + w T``; design
    effect: ``lambda V lambda`` (``lambda = diag(lambda_i)``); both with Satterthwaite
    degrees of freedom for their estimated parts ``w T`` and ``(lambda^2 - 1) V`` (``n``
    pairs behind each)."""
    n = repro.pairs
    var = repro.variance
    t2 = np.array([weight * var.get(k, 0.0) for k in names])
    v = np.maximum(np.diag(V), 0.0)
    sd_add = np.sqrt(v + t2)
    dof_add = _satterthwaite(v + t2, t2, n)
    T2 = weight * repro.block(names)
    nu = _satterthwaite(float(np.trace(V + T2)), float(np.trace(T2)), n)
    additive = joint_test(delta, V + T2, nu if math.isfinite(nu) else None)
    lam2 = np.array([repro.factor(k) for k in names])
    sd_de = np.sqrt(lam2 * v)
    # the estimated part is (lambda^2 - 1) V, behind it n pairs (Satterthwaite, as T)
    dof_de = _satterthwaite(lam2 * v, (lam2 - 1.0) * v, n)
    nu_de = _satterthwaite(float(np.sum(lam2 * v)), float(np.sum((lam2 - 1.0) * v)), n)
    z_add = _normal_equivalent(_ratio(delta, sd_add), dof_add)
    z_de = _normal_equivalent(_ratio(delta, sd_de), dof_de)
    ev = np.array([repro.support(k) for k in names])
    use_de = np.where(ev > EVIDENCE, False,
                      np.where(ev < -EVIDENCE, True, np.abs(z_de) < np.abs(z_add)))
    sd = np.where(use_de, sd_de, sd_add)
    dofs = np.where(use_de, dof_de, dof_add)
    zs = np.where(use_de, z_de, z_add)
    # the joint test: the additive one where the evidence over all parameters at once
    # (correlations included) supports it, else the milder of the two (a diagonal design
    # effect keeps V's correlations and carries none of its own: never trusted alone)
    if (repro.joint_evidence or 0.0) > EVIDENCE:
        return sd, dofs, zs, use_de, additive
    lam = np.sqrt(lam2)
    design = joint_test(delta, V * np.outer(lam, lam), nu_de if math.isfinite(nu_de)
                        else None)
    return sd, dofs, zs, use_de, (design if design[2] > additive[2] else additive)


def _ratio(delta: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``delta / sd`` (infinite where ``sd`` is zero and ``delta`` is not)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(sd > 0, delta / np.where(sd > 0, sd, 1.0),
                        np.inf * np.sign(delta))


def compare(previous: Mapping[str, Any], latest: Mapping[str, Any],
            false_alarm: float = 1e-3, reproducibility: Reproducibility | None = None,
            weight: float | None = None) -> Drift:
    """:class:`Drift` of two full records of one robot (``previous`` first);
    ``reproducibility``: the session-to-session variance ``T`` (module docstring) of the
    robot's model, estimated without this robot (None: ``T = 0``); ``weight``: ``w = 1 /
    m_a + 1 / m_b`` (None: from the records' training files)."""

    if not 0 < false_alarm < 1:
        raise KincalError(f"option --false-alarm: must be between 0 and 1 (got "
                          f"{false_alarm:g})")
    pa, Ca, ea = _robot_block(previous)
    pb, Cb, eb = _robot_block(latest)
    common = [n for n in eb if n in pa and n in pb]
    ia = [ea.index(n) for n in common]
    ib = [eb.index(n) for n in common]
    C = Ca[np.ix_(ia, ia)] + Cb[np.ix_(ib, ib)]
    delta = np.array([float(pb[n]["estimate"]) - float(pa[n]["estimate"]) for n in common])
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    dofs = np.full(len(common), math.inf)
    if reproducibility is not None:
        if weight is None:
            weight = 1.0 / placements(previous) + 1.0 / placements(latest)
        sd, dofs, zs, design, (chi2, dof, p_value) = _both_models(delta, C, common,
                                                                  reproducibility, weight)
        models = ["design effect" if d else "additive" for d in design]
    else:
        zs = _ratio(delta, sd)
        models = [""] * len(common)
        chi2, dof, p_value = joint_test(delta, C, None)
    changes = [ParameterChange(n, pb[n]["unit"], pb[n]["role"], float(pa[n]["estimate"]),
                               float(pb[n]["estimate"]), float(sd[k]), float(dofs[k]),
                               models[k], _z=float(zs[k]))
               for k, n in enumerate(common)]
    z_crit = z_threshold(len(common), false_alarm)
    changes.sort(key=lambda c: -abs(c.z))
    moved = [c for c in changes if abs(c.z) > z_crit]
    flagged = bool(moved) or p_value < false_alarm / 2
    if flagged and not moved:
        moved = changes[:3]
    return Drift(latest["serial"], (int(previous["id"]), previous["date"]),
                 (int(latest["id"]), latest["date"]), changes, chi2, dof, p_value, z_crit,
                 flagged, moved, summary_rms((latest.get("metrics") or {}).get("train")),
                 reproducibility=reproducibility)


@dataclasses.dataclass(frozen=True)
class FleetDrift:
    """The drift check of a fleet: one :class:`Drift` per robot with two calibrated
    session dates (iterating gives them), at the false-alarm probability per robot."""

    robots: list[Drift]
    false_alarm: float
    reproducibility: bool = True

    def __iter__(self) -> Iterator[Drift]:
        return iter(self.robots)

    def __len__(self) -> int:
        return len(self.robots)

    @property
    def flagged(self) -> list[Drift]:
        """The robots either test flagged."""
        return [d for d in self.robots if d.flagged]

    def reproducibility_line(self) -> str:
        """One sentence: how the session-to-session error entered the tests."""
        used = [d.reproducibility for d in self.robots if d.reproducibility is not None]
        if not self.reproducibility:
            return ("session-to-session (placement-to-placement) error left out "
                    "(--reproducibility none): the changes are judged by the calibrations' "
                    "own standard errors alone")
        if not used:
            return ("session-to-session (placement-to-placement) error not estimated (it "
                    "needs two other robots of the model with two sessions): the changes "
                    "are judged by the calibrations' own standard errors alone")
        nus = sorted({r.pairs for r in used})
        return (f"session-to-session (placement-to-placement) error estimated from "
                f"{nus[0] if len(nus) == 1 else f'{nus[0]}-{nus[-1]}'} other robot(s) of "
                f"the model ({len(used)} of {len(self.robots)} robot(s)), added to each "
                "change's covariance or grown with it (design effect): the model the "
                "other robots' changes support, else the milder verdict of the two; the "
                "thresholds allow for its uncertainty, and p = 1 where too few robots "
                "stand behind the joint test")

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``kincal fleet drift --json``."""
        return {"false_alarm": self.false_alarm, "flagged": len(self.flagged),
                "robots": [d.to_dict() for d in self.robots]}


def fleet_drift(store: Any, false_alarm: float = 1e-3,
                serials: Sequence[str] | None = None, reproducibility: bool = True
                ) -> FleetDrift:
    """:func:`compare` for every robot of a history with two calibrated session dates.

    ``reproducibility``: estimate the session-to-session variance ``T`` of each robot
    model from the other robots' pairs (module docstring); False: ``T = 0``.  The
    estimate uses every robot of the history, also when ``serials`` selects a few."""
    from kincal.fleet.store import latest_pairs

    every = latest_pairs(store.summaries())
    wanted = None if serials is None else set(serials)
    pairs = [p for p in every if wanted is None or p[1]["serial"] in wanted]
    if not pairs:
        return FleetDrift([], false_alarm, reproducibility)
    terms: dict[str, PairTerms] = {}
    if reproducibility:
        for chunk in _chunks(store, every):
            for prev, new in chunk:
                terms[new["serial"]] = pair_terms(prev, new)
    repro = fleet_reproducibility(list(terms.values()), false_alarm)
    checks = store.crosscheck_rows()
    out = []
    for chunk in _chunks(store, pairs):
        for prev, new in chunk:
            d = compare(prev, new, false_alarm, repro.get(new["serial"]))
            row = checks.get((new["id"], prev["id"]))
            if row is not None and row["status"] == "ok":
                d.rms_previous_model_m = row["rms_position_m"]
            out.append(d)
    return FleetDrift(out, false_alarm, reproducibility)


def _chunks(store: Any, pairs: Sequence[tuple[Any, Any]]
            ) -> Iterator[list[tuple[dict[str, Any], dict[str, Any]]]]:
    """The full records of ``pairs``, 200 pairs at a time (memory stays flat)."""
    for start in range(0, len(pairs), 200):
        chunk = pairs[start:start + 200]
        full = {r["id"]: r for r in store.records([x["id"] for pair in chunk for x in pair])}
        yield [(full[p["id"]], full[n["id"]]) for p, n in chunk]
