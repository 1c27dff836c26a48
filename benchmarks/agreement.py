"""Do two versions of kincal calibrate alike?  Estimates and standard errors on fixed seeds.

A speed change must not change results beyond rounding.  This script calibrates a fixed
set of simulated problems (the peer benchmark's PUMA 560 and Panda, plain least squares
and the command line's default MAP fit with tolerance priors and an estimated noise
scale, robust losses, stages, Gauss-Newton, and every registered instrument) and either
saves the outcome (``--save FILE``, e.g. on the version before the change) or compares
with a saved one (``--check FILE``).  Per problem it prints

* ``d_est``: the largest ``|theta_new - theta_old| / std_old`` over the estimated
  parameters (estimate change in units of its own standard error);
* ``d_std``: the largest ``|std_new - std_old| / std_old``;
* whether the estimated sets, the iteration counts and the convergence flags are equal.

The check fails (exit 1) when an estimated set or the convergence differs, ``d_est``
exceeds ``--tol`` (default 1e-4) or ``d_std`` exceeds ``--tol-std`` (default 1e-5).
That is the rounding floor: ``--jitter 1e-15`` (every joint reading moved by 1e-15 rad,
its last digits) moves the same problems by up to 3e-5 (``d_est``, the MAP fits: the
noise scale's fixed point stops at a 0.5 % change) and 4e-7 (``d_std``); least-squares
fits by 1e-9 to 1e-6.  Different iteration counts are listed, not failed (a step accepted
or not at a tolerance boundary).

Run::

    git stash; python benchmarks/agreement.py --save /tmp/before.json; git stash pop
    python benchmarks/agreement.py --check /tmp/before.json
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from kincal.identify.solver import calibrate  # noqa: E402
from kincal.measure.base import stack  # noqa: E402

#: ``--jitter``: added to every joint reading [rad or m] before the fit (a change of the
#: data in its last digits, to see how far rounding alone moves each problem's results).
JITTER = [0.0]


def fit(robot: Any, blocks: list[Any], **options: Any) -> Any:
    """``calibrate(robot, blocks, **options)``, the joint readings moved by ``JITTER``."""
    if JITTER[0]:
        moved = []
        for b in blocks:
            c = copy.copy(b)
            c.q = b.q + JITTER[0]
            moved.append(c)
        blocks = moved
    return calibrate(robot, blocks, **options)


def _default_prior(robot: Any, blocks: list[Any]) -> dict[str, float]:
    """The command line's default prior: the tolerances of the robot's parameters."""
    from kincal.workflow.flow import tolerances_of

    prob, _ = stack(robot, blocks)
    return tolerances_of(robot, prob).prior()


def cases() -> Iterator[tuple[str, Callable[[], Any]]]:
    """``(label, zero-argument calibration)`` for every problem of the check."""
    from calibration import peer_problem

    from kincal.measure.registry import instruments, simulate_measurements
    from kincal.measure.simulate import perturb_robot
    from kincal.robots.files import load_serial_robot

    for name, n in (("puma560", 1000), ("puma560", 10000), ("panda", 1000), ("panda", 10000)):
        robot, block, _, _ = peer_problem(name, n, holdout=10)
        yield f"{name} N={n} least squares", lambda r=robot, b=block: fit(r, [b])
        if n == 1000:
            yield (f"{name} N={n} MAP (default prior)",
                   lambda r=robot, b=block: fit(r, [b], prior=_default_prior(r, [b])))
    robot, block, _, _ = peer_problem("puma560", 1000, holdout=10)
    for loss in ("huber", "cauchy"):
        yield f"puma560 N=1000 loss {loss}", lambda lo=loss: fit(robot, [block], loss=lo)
    yield ("puma560 N=1000 stages offsets,all",
           lambda: fit(robot, [block], stages=["offsets", "all"]))
    yield ("puma560 N=1000 gauss-newton",
           lambda: fit(robot, [block], method="gauss-newton"))
    nominal = load_serial_robot("puma560")
    for inst in sorted(instruments()):
        if inst == "artifact":              # a custom artifact: no simulation without a layout
            continue
        rng = np.random.default_rng(7)
        true = perturb_robot(nominal, rng)
        noise = {"m": 1e-5, "rad": 1e-5, "px": 0.1}[instruments()[inst].noise_unit]
        blocks, _ = simulate_measurements(inst, true, rng, 60, noise)
        yield f"{inst} (60 poses) least squares", lambda b=blocks: fit(nominal, b)
        yield (f"{inst} (60 poses) MAP (default prior)",
               lambda b=blocks: fit(nominal, b, prior=_default_prior(nominal, b)))


def outcome(res: Any) -> dict[str, Any]:
    return {"names": list(res.names), "theta": res.theta.tolist(), "std": res.std.tolist(),
            "estimated": list(res.estimated), "iterations": int(res.iterations),
            "converged": bool(res.converged), "sigma0": float(res.sigma0)}


def compare(old: dict[str, Any], new: dict[str, Any]) -> tuple[float, float, list[str]]:
    """``(d_est, d_std, differences)`` of one problem (see the module docstring)."""
    notes = []
    if old["estimated"] != new["estimated"]:
        notes.append("ESTIMATED SET DIFFERS")
    if old["converged"] != new["converged"]:
        notes.append("CONVERGENCE DIFFERS")
    if old["iterations"] != new["iterations"]:
        notes.append(f"iterations {old['iterations']} -> {new['iterations']}")
    ix = [old["names"].index(n) for n in old["estimated"] if n in new["estimated"]]
    jx = [new["names"].index(old["names"][i]) for i in ix]
    so = np.asarray(old["std"])[ix]
    d_est = np.abs(np.asarray(new["theta"])[jx] - np.asarray(old["theta"])[ix]) / so
    d_std = np.abs(np.asarray(new["std"])[jx] - so) / so
    return (float(d_est.max()) if d_est.size else 0.0,
            float(d_std.max()) if d_std.size else 0.0, notes)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", help="write the outcomes to this JSON file")
    ap.add_argument("--check", help="compare with the outcomes saved in this JSON file")
    ap.add_argument("--tol", type=float, default=1e-4,
                    help="largest d_est accepted (default 1e-4)")
    ap.add_argument("--tol-std", type=float, default=1e-5,
                    help="largest d_std accepted (default 1e-5)")
    ap.add_argument("--jitter", type=float, default=0.0,
                    help="add this to every joint reading [rad / m] before each fit (e.g. "
                    "1e-15: the data changed in its last digits; shows the rounding floor)")
    a = ap.parse_args()
    JITTER[0] = a.jitter
    if bool(a.save) == bool(a.check):
        ap.error("give one of --save FILE or --check FILE")
    got = {}
    for label, run in cases():
        got[label] = outcome(run())
        print(f"  {label}", flush=True, file=sys.stderr)
    if a.save:
        Path(a.save).write_text(json.dumps(got))
        print(f"{len(got)} outcomes saved to {a.save}")
        return
    ref = json.loads(Path(a.check).read_text())
    bad = 0
    print(f"{'problem':<44}{'d_est':>10}{'d_std':>10}  notes")
    for label, new in got.items():
        if label not in ref:
            print(f"{label:<44}{'-':>10}{'-':>10}  not in {a.check}")
            continue
        d_est, d_std, notes = compare(ref[label], new)
        fail = (d_est > a.tol or d_std > a.tol_std
                or any(n.endswith("DIFFERS") for n in notes))
        bad += fail
        print(f"{label:<44}{d_est:>10.1e}{d_std:>10.1e}  {'; '.join(notes)}"
              f"{'  <- FAIL' if fail else ''}")
    print(f"{len(got) - bad} of {len(got)} problems agree (tol {a.tol:g}, {a.tol_std:g})")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
