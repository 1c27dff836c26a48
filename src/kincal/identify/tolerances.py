"""Manufacturing tolerances: the prior of a calibration and the bounds of a plausible one.

A *tolerance* ``s_j`` is one standard deviation [m / rad] of how far parameter ``j`` of
a real robot may lie from its nominal value.  It is used twice:

* as a Gaussian prior ``theta_j ~ N(nominal_j, (k s_j)^2)`` (``k`` the prior *scale*,
  1 unless model selection or the user changes it): the calibration is then the
  maximum a-posteriori estimate of :func:`kincal.identify.solver.calibrate`;
* as a plausibility bound: an estimate more than :data:`PLAUSIBLE` (10) tolerances from
  nominal is not a manufacturing deviation but a fit that went wrong or a robot file
  that is wrong (:mod:`kincal.identify.checks`).

Defaults, per parameter role (:data:`DEFAULT_TOLERANCES`):

* ``length`` 1 mm (DH ``a``, ``d``; URDF origin ``x y z``): ISO 2768-m allows
  +-0.3 mm on a machined length of 120-400 mm and +-0.5 mm up to 1000 mm; a link origin
  adds several parts, their fits and the assembly, so 1 mm is one standard deviation of
  the sum, not the tolerance of one part.
* ``angle`` 0.1 deg (DH ``alpha``, Hayati ``beta``, URDF origin error rotations):
  ISO 2768-m allows +-0.17 deg (10') on an angle whose shorter leg is 50-120 mm and
  +-0.08 deg (5') at 120-400 mm.
* ``offset`` 0.5 deg (encoder zeros; a prismatic joint's zero 1 mm): a zero is not
  machined but set, by mastering against zero marks or a calibration pin (a few
  hundredths to 0.1 deg on an industrial arm) or by homing switches (several tenths of
  a degree on service robots: TIAGo's arm_5 zero is 2.9 deg off in its real data).

Roles without a default tolerance (no prior, no plausibility bound): the robot's
``base`` and ``tool`` frames (the user's mounting and tool), and every measurement
block parameter (instrument frames, markers, probes, artifact sockets, the joint
model's hysteresis and compliance): they can be anywhere, and their initial values are
closed-form guesses, not nominal values.

Overrides, later wins: the robot file's ``tolerances:`` section (YAML robots), then the
``--prior`` text.  Both take the same entries (:func:`parse_tolerance_entries`): a role
(``length``, ``role:offset``), a parameter name or a ``*`` / ``?`` pattern, each with a
value and its unit (``1mm``, ``0.05deg``, ``20arcsec``) or ``none`` (no tolerance);
``--prior`` also takes ``none`` alone (plain least squares; the tolerances still bound
what is plausible), ``default`` and ``scale=K`` (the prior is ``K`` times the
tolerances).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from kincal.errors import KincalError

__all__ = ["DEFAULT_TOLERANCES", "PLAUSIBLE", "ROBOT_ROLES", "Tolerances",
           "parse_tolerance_entries", "parse_quantity", "resolve_tolerances",
           "describe_defaults"]

#: One standard deviation per robot parameter role and unit [m / rad] (module docstring).
DEFAULT_TOLERANCES: dict[str, dict[str, float]] = {
    "length": {"m": 1e-3},
    "angle": {"rad": math.radians(0.1)},
    "offset": {"rad": math.radians(0.5), "m": 1e-3},
}
#: Roles of robot parameters that may carry a tolerance.
ROBOT_ROLES = ("length", "angle", "offset", "base", "tool")
#: An estimate further than this many tolerances from nominal is implausible.
PLAUSIBLE = 10.0

_VALUE = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z]+)?\s*\Z")


def parse_quantity(text: str, where: str, prefix: str = "") -> tuple[float, str]:
    """``"0.1deg" -> (0.001745..., "angle")``: a positive value with its unit, in SI.

    Units are those of measurement files (``m mm um cm``, ``rad deg mrad urad arcsec``).
    ``where`` names the entry in the one-line error (``"option --prior: 'd[3]=1'"``);
    ``prefix`` starts the examples it gives (``"d[3]="``).
    """
    from kincal.units import UNITS

    m = _VALUE.match(str(text))
    if m is None:
        raise KincalError(f"{where} is not a value with a unit (e.g. 1mm or 0.1deg)")
    number, unit = float(m.group(1)), m.group(2)
    if unit is None:
        raise KincalError(f"{where} needs a unit (e.g. {prefix}{m.group(1)}mm or "
                          f"{prefix}{m.group(1)}deg)")
    if unit not in UNITS or UNITS[unit][0] not in ("length", "angle"):
        known = [u for u, (d, _) in UNITS.items() if d in ("length", "angle")]
        raise KincalError(f"{where}: unknown unit {unit!r} (known: {', '.join(known)})")
    if not (math.isfinite(number) and number > 0):
        raise KincalError(f"{where}: the standard deviation must be positive")
    dim, factor = UNITS[unit]
    return number * factor, dim


@dataclass(frozen=True)
class Entry:
    """One tolerance entry: ``target`` (a role or a name pattern) ``=`` ``value``.

    ``value`` is None for ``none`` (no tolerance); ``dimension`` ``"length"`` /
    ``"angle"`` applies the value only to parameters of that dimension.
    """

    target: str
    value: float | None
    dimension: str | None
    text: str


@dataclass(frozen=True)
class TolSpec:
    """Parsed ``--prior`` / ``tolerances:`` text: entries, ``scale``, ``use_prior``."""

    entries: tuple[Entry, ...] = ()
    scale: float = 1.0
    use_prior: bool = True
    scale_given: bool = False


def parse_tolerance_entries(text: str | Sequence[str] | Mapping[str, object] | None,
                            option: str = "option --prior") -> TolSpec:
    """Parse tolerance entries (``--prior`` text, or a robot file's ``tolerances:``).

    Accepted: ``TARGET=VALUE`` with ``TARGET`` a role (``length``, ``angle``,
    ``offset``, ``base``, ``tool``, or ``role:NAME``), a parameter name or a pattern,
    and ``VALUE`` a length or angle with its unit or ``none``; ``scale=K`` (a plain
    positive number); ``none`` (no prior at all); ``default`` (the defaults, the same as
    giving nothing).  Raises a one-line error naming ``option`` and the entry.
    """
    if text is None:
        return TolSpec()
    if isinstance(text, Mapping):
        items = [(str(k), str(v)) for k, v in text.items()]
    else:
        parts = [text] if isinstance(text, str) else list(text)
        items = []
        for chunk in parts:
            for p in (x.strip() for x in str(chunk).split(",")):
                if p:
                    target, eq, value = (s.strip() for s in p.partition("="))
                    items.append((target, value) if eq else (p, ""))
    entries: list[Entry] = []
    scale, use_prior, scale_given = 1.0, True, False
    for target, value in items:
        text_ = f"{target}={value}" if value else target
        where = f"{option}: {text_!r}"
        if not value:
            if target == "none":
                use_prior = False
                continue
            if target == "default":
                continue
            raise KincalError(f"{where} is not PATTERN=SIGMA with a unit (e.g. "
                              "'length=0.5mm,offset=0.05deg,d[3]=2mm', 'scale=3' or 'none')")
        if not target:
            raise KincalError(f"{where} names no parameter or role")
        if target == "scale":
            try:
                k = float(value)
            except ValueError:
                raise KincalError(f"{where}: the scale is a plain number (e.g. scale=3)") \
                    from None
            if not (math.isfinite(k) and k > 0):
                raise KincalError(f"{where}: the scale must be positive")
            scale, scale_given = k, True
            continue
        if value.lower() == "none":
            entries.append(Entry(target, None, None, text_))
            continue
        v, dim = parse_quantity(value, where, f"{target}=")
        entries.append(Entry(target, v, dim, text_))
    return TolSpec(tuple(entries), scale, use_prior, scale_given)


@dataclass(frozen=True)
class Tolerances:
    """The tolerances of a calibration's parameters and how the prior uses them.

    Attributes:
        sigma: ``{parameter name: tolerance}`` [m / rad] (names without one absent).
        source: ``{parameter name: where its tolerance came from}`` ("default length",
            "robot file", "--prior").
        scale: the prior's standard deviation is ``scale * sigma``.
        use_prior: False for plain least squares (``--prior none``).
    """

    sigma: dict[str, float] = field(default_factory=dict)
    source: dict[str, str] = field(default_factory=dict)
    scale: float = 1.0
    use_prior: bool = True

    def prior(self, names: Sequence[str] | None = None) -> dict[str, float]:
        """``{name: prior standard deviation}`` for the solver (empty without a prior)."""
        if not self.use_prior:
            return {}
        return {n: s * self.scale for n, s in self.sigma.items()
                if names is None or n in names}

    def with_scale(self, scale: float | None) -> Tolerances:
        """The same tolerances with prior scale ``scale`` (None: no prior)."""
        if scale is None:
            return Tolerances(dict(self.sigma), dict(self.source), 1.0, False)
        return Tolerances(dict(self.sigma), dict(self.source), float(scale), True)

    def label(self) -> str:
        """``"prior x1"``, ``"prior x3"``, ``"least squares"`` (for tables)."""
        return f"prior x{self.scale:g}" if self.use_prior else "least squares"

    def to_dict(self) -> dict[str, object]:
        return {"use_prior": self.use_prior, "scale": self.scale,
                "tolerances": {n: {"sigma": s, "source": self.source.get(n, "")}
                               for n, s in self.sigma.items()}}


def _apply(entries: Sequence[Entry], names: Sequence[str], units: Sequence[str],
           roles: Sequence[str], sigma: dict[str, float], source: dict[str, str],
           label: str, option: str) -> None:
    from kincal.identify.names import match_names

    dims = [{"m": "length", "rad": "angle"}.get(u) for u in units]
    for e in entries:
        role = e.target[5:] if e.target.startswith("role:") else \
            e.target if e.target in ROBOT_ROLES else None
        if role is not None:
            hit = [i for i, r in enumerate(roles) if r == role]
            if not hit:
                raise KincalError(f"{option}: {e.text!r}: no parameter has role {role!r} "
                                  f"(roles: {', '.join(sorted(set(roles)))})")
        else:
            try:
                hit = match_names(names, e.target)
            except KincalError as exc:
                raise KincalError(f"{option}: {exc}") from None
        if e.dimension is not None:
            hit = [i for i in hit if dims[i] == e.dimension]
            if not hit:
                article = "an" if e.dimension[0] in "aeiou" else "a"
                raise KincalError(f"{option}: {e.target!r} matches no {e.dimension} parameter "
                                  f"(the unit of {e.text!r} is {article} {e.dimension})")
        for i in hit:
            if e.value is None:
                sigma.pop(names[i], None)
                source.pop(names[i], None)
            else:
                sigma[names[i]] = e.value
                source[names[i]] = label


def resolve_tolerances(names: Sequence[str], units: Sequence[str], roles: Sequence[str],
                       robot_file: Mapping[str, object] | Sequence[str] | str | None = None,
                       prior: str | TolSpec | None = None, *, robot_source: str = "robot file",
                       defaults: Mapping[str, Mapping[str, float]] | None = None
                       ) -> Tolerances:
    """The tolerance of every parameter: role defaults, robot file, then ``--prior``.

    Args:
        names, units, roles: the calibration problem's parameters (robot, then blocks).
        robot_file: the robot file's ``tolerances:`` entries (``robot.meta["tolerances"]``).
        prior: ``--prior`` text (or an already parsed :class:`TolSpec`).
        robot_source: the robot file's name, for messages.
        defaults: role -> unit -> tolerance (default :data:`DEFAULT_TOLERANCES`).

    Only robot roles get a default (block parameters have none).
    """
    base = DEFAULT_TOLERANCES if defaults is None else defaults
    sigma: dict[str, float] = {}
    source: dict[str, str] = {}
    for n, u, r in zip(names, units, roles, strict=True):
        if u in base.get(r, {}):
            sigma[n] = float(base[r][u])
            source[n] = f"default {r}"
    if robot_file:
        spec = parse_tolerance_entries(robot_file, f"{robot_source}: tolerances")
        _apply(spec.entries, names, units, roles, sigma, source, "robot file",
               f"{robot_source}: tolerances")
    spec = prior if isinstance(prior, TolSpec) else parse_tolerance_entries(prior)
    _apply(spec.entries, names, units, roles, sigma, source, "--prior", "option --prior")
    return Tolerances(sigma, source, spec.scale, spec.use_prior)


def describe_defaults() -> str:
    """``"length 1 mm, angle 0.1 deg, offset 0.1 deg (prismatic 1 mm)"``: the defaults."""
    def one(unit: str, s: float) -> str:
        return f"{s * 1e3:g} mm" if unit == "m" else f"{math.degrees(s):g} deg"

    parts = []
    for role, by_unit in DEFAULT_TOLERANCES.items():
        (u0, s0), *more = by_unit.items()
        extra = "".join(f" (prismatic {one(u, s)})" for u, s in more)
        parts.append(f"{role} {one(u0, s0)}{extra}")
    return ", ".join(parts)
