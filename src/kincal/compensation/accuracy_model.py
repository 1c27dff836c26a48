"""The calibrated model's accuracy where a program sends the robot, from a result JSON.

``kincal calibrate --json`` stores the covariance of the estimated robot parameters and
the joint ranges the training data covered (``accuracy_model``, written by
:func:`accuracy_document`).  :func:`accuracy_from_document` turns it back into an
:data:`~kincal.compensation.filter.AccuracyModel` for ``kincal filter --result``:

* predicted position std at a point ``m`` of the flange frame (the program's TCP):
  ``sqrt(trace(G C G^T))`` with ``G = J_v - [R m]x J_w`` the position rows of the
  parameter Jacobian of that point and ``C`` the covariance [m];
* inside the calibrated region when every joint lies within the training range (the
  model extrapolates outside it).

The covariance is the marginal one of the robot parameters (the instrument's frame and
marker are nuisance parameters of the training session).  Units: SI.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot
from kincal.spatial import skew

Array = NDArray[np.float64]


def accuracy_document(result: Any) -> dict[str, Any] | None:
    """``{"parameters", "covariance", "joint_names", "joint_min", "joint_max"}`` of a
    calibration result (robot parameters only), or None when it has no covariance."""
    cov = getattr(result, "covariance", None)
    est = list(getattr(result, "estimated", []))
    robot = getattr(result, "robot", None)
    if cov is None or robot is None or not est or not hasattr(robot, "param_names"):
        return None
    keep = [i for i, n in enumerate(est) if n in robot.param_names]
    qs = [np.asarray(b.q, dtype=float) for b in result.problem.blocks if hasattr(b, "q")
          and np.ndim(b.q) == 2 and np.shape(b.q)[1] == robot.n]
    if not qs:
        return None
    q = np.vstack(qs)
    C = np.asarray(cov, dtype=float)[np.ix_(keep, keep)]
    return {"parameters": [est[i] for i in keep], "covariance": C.tolist(),
            "joint_names": list(robot.joint_names), "joint_min": q.min(axis=0).tolist(),
            "joint_max": q.max(axis=0).tolist(),
            "note": "covariance of the estimated robot parameters (m, rad); joint ranges of "
                    "the training data (rad, m)"}


def accuracy_from_document(doc: Mapping[str, Any], robot: Robot, source: str = "result"
                           ) -> Any:
    """An accuracy model ``(q (N, n), tcp (N, 3)) -> (std (N,), inside (N,))`` of ``robot``
    from a result JSON's ``accuracy_model``."""
    m = doc.get("accuracy_model")
    if not isinstance(m, Mapping):
        raise KincalError("has no accuracy_model (written by `kincal calibrate --json`)",
                          source=source)
    names = list(m["parameters"])
    missing = [n for n in names if n not in robot.param_names]
    if missing or list(m["joint_names"]) != list(robot.joint_names):
        raise KincalError(f"its accuracy model is for another robot (parameters "
                          f"{', '.join(missing[:3]) or 'or joints differ'})", source=source)
    C = np.asarray(m["covariance"], dtype=float)
    lo, hi = np.asarray(m["joint_min"], float), np.asarray(m["joint_max"], float)

    def model(q: Array, tcp: Array) -> tuple[Array, NDArray[np.bool_]]:
        T, _, Jp = robot.fk_with_jacobians(q, joints=False, params=True)
        J = Jp[:, :, robot.param_indices(names)]
        a = np.einsum("nij,nj->ni", T[:, :3, :3], tcp)                 # R m
        G = J[:, :3, :] - np.einsum("nij,njp->nip", skew(a), J[:, 3:, :])
        std = np.sqrt(np.clip(np.einsum("nip,pq,niq->n", G, C, G), 0.0, None))
        inside = np.all((q >= lo - 1e-9) & (q <= hi + 1e-9), axis=1)
        return std, inside

    return model
