"""DH, modified DH and Hayati front ends against the textbook link matrices."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.robots.dh import DHLink, dh_links, from_dh, standard_to_modified
from kincal.spatial import matrix_from_frame

RNG = np.random.default_rng(3)
PI = np.pi
BASE = (0.1, 0.2, 0.3, 0.3, -0.2, 0.1)          # x y z rz ry rx
TOOL = (0.01, 0.02, 0.1, -0.1, 0.2, 0.3)


def A_standard(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard DH link matrix (Spong / Siciliano)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0, sa, ca, d],
                     [0, 0, 0, 1.0]])


def A_modified(alpha: float, a: float, theta: float, d: float) -> np.ndarray:
    """Modified DH link matrix (Craig): Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st, 0, a],
                     [st * ca, ct * ca, -sa, -sa * d],
                     [st * sa, ct * sa, ca, ca * d],
                     [0, 0, 0, 1.0]])


def Ry(beta: float) -> np.ndarray:
    c, s = np.cos(beta), np.sin(beta)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def puma_like(prismatic: int | None = 3) -> list[DHLink]:
    tab = [(0, 0, PI / 2), (0.4318, 0, 0), (0.0203, 0.15005, -PI / 2), (0, 0.4318, PI / 2),
           (0, 0, -PI / 2), (0, 0.05, 0)]
    links = [DHLink(a=a, d=d, alpha=al, theta_offset=0.1 * i, lower=-2.5, upper=2.5)
             for i, (a, d, al) in enumerate(tab)]
    if prismatic is not None:
        links[prismatic] = DHLink(a=0.01, d=0.4318, alpha=PI / 2, theta_offset=0.2,
                                  joint="prismatic", lower=0.0, upper=0.3)
    return links


def reference_standard(links, q, base=BASE, tool=TOOL, betas=None) -> np.ndarray:
    T = matrix_from_frame(base)
    for i, L in enumerate(links):
        th, d = L.theta_offset, L.d
        if L.joint == "revolute":
            th = th + q[i]
        else:
            d = d + q[i]
        T = T @ A_standard(th, d, L.a, L.alpha)
        if betas is not None:
            T = T @ Ry(betas[i])
    return T @ matrix_from_frame(tool)


def reference_modified(links, q, base=BASE, tool=TOOL) -> np.ndarray:
    T = matrix_from_frame(base)
    for i, L in enumerate(links):
        th, d = L.theta_offset, L.d
        if L.joint == "revolute":
            th = th + q[i]
        else:
            d = d + q[i]
        T = T @ A_modified(L.alpha, L.a, th, d)
    return T @ matrix_from_frame(tool)


@pytest.mark.parametrize("prismatic", [None, 0, 3, 5])
def test_standard_dh_equals_textbook_product(prismatic):
    links = puma_like(prismatic)
    robot = from_dh(links, base=BASE, tool=TOOL)
    Q = RNG.uniform(-2, 2, (20, 6))
    T = robot.fk(Q)
    for q, Tq in zip(Q, T, strict=True):
        np.testing.assert_allclose(Tq, reference_standard(links, q), atol=1e-12)
    assert robot.meta["convention"] == "standard_dh"
    kinds = [j.kind for j in robot.joints]
    assert kinds.count("prismatic") == (0 if prismatic is None else 1)


@pytest.mark.parametrize("prismatic", [None, 2])
def test_modified_dh_equals_craig_product(prismatic):
    links = puma_like(prismatic)
    robot = from_dh(links, "modified", base=BASE, tool=TOOL)
    Q = RNG.uniform(-2, 2, (20, 6))
    for q, Tq in zip(Q, robot.fk(Q), strict=True):
        np.testing.assert_allclose(Tq, reference_modified(links, q), atol=1e-12)
    assert robot.meta["convention"] == "modified_dh"


@pytest.mark.parametrize("prismatic", [None, 0, 3, 5])
def test_standard_to_modified_keeps_the_kinematics(prismatic):
    robot = from_dh(puma_like(prismatic), base=BASE, tool=TOOL, name="p", meta={"source": "s"})
    mod = standard_to_modified(robot)
    assert mod.meta["convention"] == "modified_dh" and mod.meta["source"] == "s"
    Q = RNG.uniform(-2, 2, (50, 6))
    np.testing.assert_allclose(mod.fk(Q), robot.fk(Q), atol=1e-12)
    np.testing.assert_allclose(mod.jacobian(Q), robot.jacobian(Q), atol=1e-12)
    # the modified table is the standard one shifted by one row; the last (a, alpha)
    # moved into the tool frame
    std, m = dh_links(robot), dh_links(mod)
    assert m[0].a == 0 and m[0].alpha == 0
    for i in range(1, 6):
        assert (m[i].a, m[i].alpha) == (std[i - 1].a, std[i - 1].alpha)
        assert (m[i].d, m[i].theta_offset, m[i].joint) == (std[i].d, std[i].theta_offset,
                                                            std[i].joint)
    np.testing.assert_allclose(mod.frame_parameters("base"), BASE, atol=0)
    # the same kinematics written independently in Craig's form
    for q in Q[:5]:
        np.testing.assert_allclose(reference_modified(m, q, tool=mod.frame_parameters("tool")),
                                   robot.fk(q), atol=1e-12)


def test_hayati_beta_zero_equals_plain_dh():
    links = puma_like(3)
    plain = from_dh(links, base=BASE, tool=TOOL)
    hay_links = [DHLink(**{**L.__dict__, "beta": 0.0}) if i in (1, 2) else L
                 for i, L in enumerate(links)]
    hayati = from_dh(hay_links, base=BASE, tool=TOOL)
    assert hayati.meta["convention"] == "hayati"
    assert {"beta[2]", "beta[3]"} <= set(hayati.param_names)
    assert "beta[1]" not in hayati.param_names
    Q = RNG.uniform(-2, 2, (30, 6))
    np.testing.assert_allclose(hayati.fk(Q), plain.fk(Q), atol=1e-15)
    np.testing.assert_allclose(hayati.jacobian(Q), plain.jacobian(Q), atol=1e-15)


def test_hayati_nonzero_beta_equals_explicit_product():
    links = puma_like(3)
    betas = [0.0, 0.013, -0.02, 0.0, 0.05, 0.0]
    hay_links = [DHLink(**{**L.__dict__, "beta": b}) for L, b in zip(links, betas, strict=True)]
    robot = from_dh(hay_links, base=BASE, tool=TOOL)
    Q = RNG.uniform(-2, 2, (20, 6))
    for q, Tq in zip(Q, robot.fk(Q), strict=True):
        np.testing.assert_allclose(Tq, reference_standard(links, q, betas=betas), atol=1e-12)
    # and it really differs from plain DH
    assert np.abs(robot.fk(Q) - from_dh(links, base=BASE, tool=TOOL).fk(Q)).max() > 1e-3
    with pytest.raises(KincalError, match="not in standard DH"):
        standard_to_modified(robot)


def test_dh_links_round_trip_and_errors():
    links = puma_like(3)
    robot = from_dh(links, base=BASE, tool=TOOL)
    back = dh_links(robot)
    for L, B in zip(links, back, strict=True):
        for f in ("a", "d", "alpha", "theta_offset", "joint", "lower", "upper"):
            assert getattr(B, f) == getattr(L, f)
    assert [j.name for j in robot.joints] == [f"q{i}" for i in range(1, 7)]
    np.testing.assert_allclose(robot.frame_parameters("tool"), TOOL, atol=0)
    with pytest.raises(KincalError, match="unknown DH convention"):
        from_dh(links, "craig")  # type: ignore[arg-type]
    with pytest.raises(KincalError, match="beta"):
        from_dh([DHLink(beta=0.1)], "modified")
