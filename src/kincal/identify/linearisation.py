"""The current point of a solver stage, its residuals and its QR triangle, reused where safe.

Each iteration of a stage linearises the weighted problem at the current point ``theta``
into its QR triangle ``[W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]``
(:meth:`~kincal.measure.base.StackedProblem.compressed`), built piece by piece in one pass
over the data that also yields the residual vector ``r`` (M,).  :class:`Linearisation`
keeps that triangle (without ``r``) and decides what else is kept:

* **reuse of a trial's triangle** (only when the weights do not depend on the residuals,
  loss ``"linear"``): a trial point is evaluated by building its triangle with its
  residuals in the same pass (:meth:`Linearisation.trial`); when the step is taken that
  triangle *is* the next linearisation, so no forward kinematics is evaluated twice at the
  same ``theta``.  A step shorter than ``tol_step`` ends the stage; its triangle is not
  built and the one where the step started stands for it (:attr:`Linearisation.exact`
  is then False: ``J`` differs by less than the step).
* **one residual vector at a time**: while a step is tried the current residuals are
  dropped (:meth:`Linearisation.drop_residuals`) and the triangle's ``cost = 1/2 (|z|^2 +
  rho^2)`` stands for theirs; they are evaluated again only when the stage ends at the
  current point, unless the vector is small: at most ``KEEP_RESIDUALS_BYTES`` (8 MiB) it
  is kept beside its triangle.  Memory beyond the data: ``O(P^2 + one piece)`` and one
  (M,) vector (two while a kept one waits).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from kincal.measure.base import CompressedSystem

Array = NDArray[np.float64]

#: A stage keeps the residual vector of its current point next to its triangle when the
#: vector is at most this large [bytes], so a stage that ends there does not evaluate
#: it again; larger problems keep one residual vector at a time.
KEEP_RESIDUALS_BYTES = 8 << 20


class LinearisedProblem(Protocol):
    """What a stage needs of its problem: residuals and the weighted QR triangle."""

    def residuals(self, theta: Array) -> Array:
        """Whitened residuals (M,) at ``theta``."""
        ...

    def compressed(self, theta: Array, weights: Array, columns: Sequence[int]
                   ) -> CompressedSystem:
        """The weighted problem over ``columns`` at ``theta`` as a QR triangle with its
        residual vector ``r``."""
        ...

    def num_residuals(self) -> int:
        """M, the number of residual rows."""
        ...


def half_weighted_ss(r: Array, w: Array) -> float:
    """``1/2 sum w r^2`` without an (M,) temporary when the weights are uniform."""
    if not r.size:
        return 0.0
    if w.ndim and w.strides[0] == 0:
        return 0.5 * float(w[0]) * float(r @ r)
    return 0.5 * float((w * r) @ r)


class Linearisation:
    """The point a stage stands at: ``theta``, its residuals and its triangle.

    Args:
        problem: the stage's problem (a stacked problem, or one with prior rows).
        theta: the starting point.
        start: the triangle at ``theta`` with its residual vector, if the caller has it.
        reuse_trials: weights independent of the residuals (loss ``"linear"``): trial
            triangles are built and reused, residuals are dropped while a step is tried.
    """

    def __init__(self, problem: LinearisedProblem, theta: Array,
                 start: CompressedSystem | None, reuse_trials: bool) -> None:
        self.problem = problem
        self.reuse_trials = reuse_trials
        self.keep_residuals = (reuse_trials
                               and 8 * problem.num_residuals() <= KEEP_RESIDUALS_BYTES)
        self.theta = theta
        #: the triangle (without ``r``) at :attr:`triangle_theta`, or None
        self.triangle: CompressedSystem | None = (None if start is None
                                                  else dataclasses.replace(start, r=None))
        #: where :attr:`triangle` was built
        self.triangle_theta = theta
        #: the residuals at ``theta``, or None while dropped
        self.r: Array | None = None if start is None else start.r
        #: the residuals where the triangle was built, kept when small
        self.kept: Array | None = self.r if self.keep_residuals else None
        if self.r is None and not (reuse_trials and start is not None):
            self.r = problem.residuals(theta)

    @property
    def exact(self) -> bool:
        """The triangle was built at ``theta`` (not where a last tiny step started)."""
        return self.triangle_theta is self.theta

    def residuals(self) -> Array:
        """The residuals at ``theta``: those held, those kept beside the triangle, or
        evaluated again."""
        if self.r is None:
            self.r = (self.kept if self.kept is not None and self.exact
                      else self.problem.residuals(self.theta))
        return self.r

    def cost(self, w: Array) -> float:
        """``1/2 sum w r^2`` at ``theta``: from the residuals, or (uniform weights) the
        triangle's cost when they were dropped."""
        if self.r is None and self.triangle is not None and self.reuse_trials:
            return float(self.triangle.cost)
        return half_weighted_ss(self.residuals(), w)

    def rms(self, w: Array) -> float:
        """RMS of the whitened residuals at ``theta`` (from the cost while they are
        dropped: ``sqrt(2 cost / w / M)`` with uniform weights ``w``)."""
        cost = self.cost(w)
        size = w.size
        if not size:
            return 0.0
        if self.r is None:
            return float(np.sqrt(2.0 * cost / float(w[0]) / size))
        return float(np.sqrt(self.r @ self.r / size))

    def linearise(self, w: Array, columns: Sequence[int]) -> CompressedSystem:
        """The triangle at ``theta`` over ``columns`` (built now unless held)."""
        if self.triangle is None:
            C = self.problem.compressed(self.theta, w, columns)
            self.r = C.r
            self.triangle, self.triangle_theta = dataclasses.replace(C, r=None), self.theta
            self.kept = self.r if self.keep_residuals else None
        return self.triangle

    def drop_residuals(self) -> None:
        """Forget the residuals while a step is tried (one vector in memory)."""
        self.r = None

    def trial(self, theta: Array, w: Array, columns: Sequence[int], build: bool
              ) -> tuple[CompressedSystem | None, Array]:
        """Evaluate a trial point: ``(its triangle or None, its residuals)``.

        The triangle is built (with the residuals, in one pass) when ``build`` and the
        trials are reused; otherwise only the residuals are evaluated.
        """
        C = self.problem.compressed(theta, w, columns) if self.reuse_trials and build \
            else None
        r = self.problem.residuals(theta) if C is None else C.r
        assert r is not None                    # C.r: built with its residuals
        return C, r

    def move(self, theta: Array, r: Array, triangle: CompressedSystem | None,
             tiny: bool) -> None:
        """Take a step to ``theta`` with its residuals ``r`` and its triangle if built.

        Without a triangle the next iteration builds one, except after a step shorter
        than ``tol_step`` (``tiny``) with reused trials: the stage ends there and the
        triangle where the step started stands for it.
        """
        self.theta, self.r = theta, r
        if triangle is not None:
            self.triangle = dataclasses.replace(triangle, r=None)
            self.triangle_theta = theta
            self.kept = r if self.keep_residuals else None
        elif not (self.reuse_trials and tiny):
            self.triangle = None
