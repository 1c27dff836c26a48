"""Mobility (degrees of freedom) of a mechanism: the Kutzbach/Grübler count.

A mechanism is a set of rigid links (the ground counted as one of them) joined
by joints, each joint allowing ``f_i`` relative freedoms.  In a space of
dimension ``lam`` (3 for planar motion, 6 for spatial motion) a free link has
``lam`` freedoms and a joint removes ``lam - f_i`` of them, so

    F = lam * (n - 1) - sum_i (lam - f_i) = lam * (n - j - 1) + sum_i f_i     (Kutzbach)

with ``n`` links and ``j`` joints.  The same number follows from the number of
independent loops of the link graph (Euler), ``L = j - n + c`` with ``c``
connected components (1 for a connected mechanism):

    F = sum_i f_i - lam * L + lam * (c - 1)                                   (Grübler)

which equals the Kutzbach count for a connected mechanism.  Both are counts:
special geometry (parallel axes, equal links) can make the true mobility larger.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from kincal.errors import KincalError

SPACE_DIMENSION = {"planar": 3, "spherical": 3, "spatial": 6}


@dataclass(frozen=True)
class Joint:
    """A joint between two named links allowing ``freedom`` relative freedoms.

    Revolute and prismatic joints have freedom 1, a cylindrical or a
    revolute+screw pair 2, a spherical joint 3.
    """

    name: str
    links: tuple[str, str]
    freedom: int = 1


@dataclass(frozen=True)
class Mechanism:
    """Links (names; the first is the ground) and the joints that connect them."""

    links: tuple[str, ...]
    joints: tuple[Joint, ...]
    space: str = "planar"

    def __post_init__(self) -> None:
        if self.space not in SPACE_DIMENSION:
            raise KincalError(
                f"mechanism space must be one of {sorted(SPACE_DIMENSION)}, not {self.space!r}"
            )
        if len(set(self.links)) != len(self.links):
            raise KincalError("mechanism link names must be unique")
        known = set(self.links)
        lam = SPACE_DIMENSION[self.space]
        for joint in self.joints:
            for link in joint.links:
                if link not in known:
                    raise KincalError(f"joint {joint.name!r} names unknown link {link!r}")
            if joint.links[0] == joint.links[1]:
                raise KincalError(f"joint {joint.name!r} joins link {joint.links[0]!r} to itself")
            if not 1 <= joint.freedom < lam:
                raise KincalError(
                    f"joint {joint.name!r} freedom must be between 1 and {lam - 1}, "
                    f"not {joint.freedom}"
                )

    @property
    def dimension(self) -> int:
        """lam: freedoms of a free body (3 planar, 6 spatial)."""
        return SPACE_DIMENSION[self.space]

    def components(self) -> int:
        """Number of connected components of the link graph (union-find)."""
        parent = {link: link for link in self.links}

        def root(link: str) -> str:
            while parent[link] != link:
                parent[link] = parent[parent[link]]
                link = parent[link]
            return link

        for joint in self.joints:
            a, b = (root(link) for link in joint.links)
            if a != b:
                parent[a] = b
        return len({root(link) for link in self.links})

    def loops(self) -> int:
        """Independent closed loops, Euler: ``L = j - n + c``."""
        return len(self.joints) - len(self.links) + self.components()

    def kutzbach(self) -> int:
        """Kutzbach count ``F = lam (n - j - 1) + sum f_i``."""
        lam = self.dimension
        n, j = len(self.links), len(self.joints)
        return lam * (n - j - 1) + sum(joint.freedom for joint in self.joints)

    def grubler(self) -> int:
        """Grübler count ``F = sum f_i - lam L`` (plus ``lam (c-1)`` for loose parts)."""
        lam = self.dimension
        return (
            sum(joint.freedom for joint in self.joints)
            - lam * self.loops()
            + lam * (self.components() - 1)
        )


def mobility(
    links: Sequence[str] | int,
    joints: Sequence[Joint | tuple[str, str, int]],
    space: str = "planar",
) -> int:
    """Kutzbach/Grübler mobility of a mechanism.

    Args:
        links: link names (ground included) or just their number ``n``; with a
            number only the Kutzbach count is possible, so joints then need no
            valid link names.
        joints: :class:`Joint` values or ``(link_a, link_b, freedom)`` tuples.
        space: ``"planar"`` (lam = 3) or ``"spatial"`` (lam = 6).

    Returns:
        F = lam (n - j - 1) + sum f_i.
    """
    parsed = tuple(
        j if isinstance(j, Joint) else Joint(f"J{k + 1}", (j[0], j[1]), int(j[2]))
        for k, j in enumerate(joints)
    )
    if isinstance(links, int):
        lam = SPACE_DIMENSION[space]
        return lam * (links - len(parsed) - 1) + sum(j.freedom for j in parsed)
    return Mechanism(tuple(links), parsed, space).kutzbach()


def planar_five_bar() -> Mechanism:
    """The planar five-bar: ground B1-B2, proximal l1, l2, distal l3, l4, five revolutes.

    F = 3 (5 - 5 - 1) + 5 = 2.
    """
    links = ("ground", "l1", "l2", "l3", "l4")
    joints = (
        Joint("B1", ("ground", "l1")),
        Joint("B2", ("ground", "l2")),
        Joint("J1", ("l1", "l3")),
        Joint("J2", ("l2", "l4")),
        Joint("J3", ("l3", "l4")),
    )
    return Mechanism(links, joints, "planar")


def dual_scara_thesis() -> Mechanism:
    """The dual SCARA as counted in Pittr (2012), section 3.1.

    Links: the base <M1,M2>, <M1,K1>, <M2,K2>, <K1,K3>, <K2,K3> and the effector
    E1; joints M1, M2, K1, K2, K3 (revolute, f = 1) and E1 (revolute + screw,
    f = 2), counted with lam = 3:  F = 3 (6 - 6 - 1) + 7 = 4, one loop
    M1-K1-K3-K2-M2.
    """
    links = ("M1M2", "M1K1", "M2K2", "K1K3", "K2K3", "E1")
    joints = (
        Joint("M1", ("M1M2", "M1K1")),
        Joint("M2", ("M1M2", "M2K2")),
        Joint("K1", ("M1K1", "K1K3")),
        Joint("K2", ("M2K2", "K2K3")),
        Joint("K3", ("K1K3", "K2K3")),
        Joint("E1", ("K1K3", "E1"), 2),
    )
    return Mechanism(links, joints, "planar")
