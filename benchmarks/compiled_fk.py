"""Does a compiled kernel pay?  kincal's NumPy forward kinematics against numba versions.

kincal keeps a compiled kernel only if forward kinematics and the parameter Jacobian get
at least 3x faster at N >= 10^4 (goal: <= 90 ns per 6R configuration).  This script
measures the forward-kinematics half of that question with two numba kernels of the
same compiled chain (the constant transforms between joints multiplied out once):

* ``numba, libm trig``: one configuration at a time, scalar ``cos``/``sin``, the running
  frame as a 3x4 array;
* ``numba, NumPy trig``: ``cos``/``sin`` of all joint values by NumPy first (its SIMD
  transcendental functions), then the frame products in numba with the frame held in
  twelve scalars (``fastmath``).

Both are checked against ``Robot.fk`` first.  Times are CPU (process) times, medians of
interleaved rounds (:mod:`timing`), per configuration.  numba is not a dependency of
kincal: ``pip install numba`` in the benchmark environment.

    python benchmarks/compiled_fk.py [--sizes 10000,100000] [--rounds 7]
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from timing import interleaved, machine  # noqa: E402

from kincal.measure.simulate import random_configurations  # noqa: E402
from kincal.robots.chain import elementary_matrix  # noqa: E402
from kincal.robots.files import load_serial_robot  # noqa: E402

_AXIS = {"Rx": 0, "Ry": 1, "Rz": 2, "Tx": 0, "Ty": 1, "Tz": 2}


def compile_chain(robot):
    """Prefix (3, 4), posts (J, 4, 4), joint axes, joint of each carrier, scale, offset."""
    ets, pv = robot.ets, robot.param_values
    val = [float(pv[e.param]) if e.param >= 0 else e.constant for e in ets]
    carriers = [k for k, e in enumerate(ets) if e.joint >= 0]
    if not all(ets[k].is_rotation for k in carriers):
        raise SystemExit("this prototype handles revolute joints only")

    def product(a: int, b: int) -> np.ndarray:
        G = np.eye(4)
        for k in range(a, b):
            G = G @ elementary_matrix(ets[k].kind, val[k])
        return G

    bounds = carriers + [len(ets)]
    prefix = product(0, carriers[0])[:3].copy()
    posts = np.array([product(k + 1, bounds[m + 1]) for m, k in enumerate(carriers)])
    axes = np.array([_AXIS[ets[k].kind] for k in carriers])
    joint = np.array([ets[k].joint for k in carriers])
    scale = np.array([ets[k].scale for k in carriers])
    offset = np.array([val[k] for k in carriers])
    return prefix, posts, axes, joint, scale, offset


def kernels():
    from numba import njit

    @njit(cache=True)
    def fk_libm(q, prefix, posts, axes, joint, scale, offset, out):
        N, J = q.shape[0], posts.shape[0]
        F = np.empty((3, 4))
        G = np.empty((3, 4))
        for n in range(N):
            F[:, :] = prefix
            for m in range(J):
                v = offset[m] + scale[m] * q[n, joint[m]]
                c, s = np.cos(v), np.sin(v)
                i1, i2 = (axes[m] + 1) % 3, (axes[m] + 2) % 3
                for r in range(3):
                    A, B = F[r, i1], F[r, i2]
                    F[r, i1] = c * A + s * B
                    F[r, i2] = c * B - s * A
                P = posts[m]
                for r in range(3):
                    for j in range(4):
                        acc = F[r, 0] * P[0, j] + F[r, 1] * P[1, j] + F[r, 2] * P[2, j]
                        G[r, j] = acc + F[r, 3] if j == 3 else acc
                F[:, :] = G
            out[n] = F

    @njit(cache=True, fastmath=True)
    def fk_scalars(cs, sn, prefix, posts, axes, out):
        J, N = cs.shape
        for n in range(N):
            f = prefix.copy()
            F00, F01, F02, F03 = f[0, 0], f[0, 1], f[0, 2], f[0, 3]
            F10, F11, F12, F13 = f[1, 0], f[1, 1], f[1, 2], f[1, 3]
            F20, F21, F22, F23 = f[2, 0], f[2, 1], f[2, 2], f[2, 3]
            for m in range(J):
                c, s, a = cs[m, n], sn[m, n], axes[m]
                if a == 2:
                    F00, F01 = c * F00 + s * F01, c * F01 - s * F00
                    F10, F11 = c * F10 + s * F11, c * F11 - s * F10
                    F20, F21 = c * F20 + s * F21, c * F21 - s * F20
                elif a == 0:
                    F01, F02 = c * F01 + s * F02, c * F02 - s * F01
                    F11, F12 = c * F11 + s * F12, c * F12 - s * F11
                    F21, F22 = c * F21 + s * F22, c * F22 - s * F21
                else:
                    F02, F00 = c * F02 + s * F00, c * F00 - s * F02
                    F12, F10 = c * F12 + s * F10, c * F10 - s * F12
                    F22, F20 = c * F22 + s * F20, c * F20 - s * F22
                P = posts[m]
                F00, F01, F02, F03 = (F00 * P[0, 0] + F01 * P[1, 0] + F02 * P[2, 0],
                                      F00 * P[0, 1] + F01 * P[1, 1] + F02 * P[2, 1],
                                      F00 * P[0, 2] + F01 * P[1, 2] + F02 * P[2, 2],
                                      F00 * P[0, 3] + F01 * P[1, 3] + F02 * P[2, 3] + F03)
                F10, F11, F12, F13 = (F10 * P[0, 0] + F11 * P[1, 0] + F12 * P[2, 0],
                                      F10 * P[0, 1] + F11 * P[1, 1] + F12 * P[2, 1],
                                      F10 * P[0, 2] + F11 * P[1, 2] + F12 * P[2, 2],
                                      F10 * P[0, 3] + F11 * P[1, 3] + F12 * P[2, 3] + F13)
                F20, F21, F22, F23 = (F20 * P[0, 0] + F21 * P[1, 0] + F22 * P[2, 0],
                                      F20 * P[0, 1] + F21 * P[1, 1] + F22 * P[2, 1],
                                      F20 * P[0, 2] + F21 * P[1, 2] + F22 * P[2, 2],
                                      F20 * P[0, 3] + F21 * P[1, 3] + F22 * P[2, 3] + F23)
            out[n, 0, 0], out[n, 0, 1], out[n, 0, 2], out[n, 0, 3] = F00, F01, F02, F03
            out[n, 1, 0], out[n, 1, 1], out[n, 1, 2], out[n, 1, 3] = F10, F11, F12, F13
            out[n, 2, 0], out[n, 2, 1], out[n, 2, 2], out[n, 2, 3] = F20, F21, F22, F23

    return fk_libm, fk_scalars


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args()
    try:
        import numba
    except ImportError:
        raise SystemExit("numba is not installed here: pip install numba") from None
    fk_libm, fk_scalars = kernels()
    robot = load_serial_robot("puma560")
    prefix, posts, axes, joint, scale, offset = compile_chain(robot)
    print(f"PUMA 560 forward kinematics, numba {numba.__version__}; {machine()}")
    print(f"{'N':>8}{'NumPy [ns]':>12}{'numba libm [ns]':>17}{'numba+NumPy trig [ns]':>23}"
          f"{'best speed-up':>15}")
    for N in (int(s) for s in a.sizes.split(",")):
        q = random_configurations(robot, N, np.random.default_rng(0))
        out = np.empty((N, 3, 4))

        def libm(q=q, out=out):
            fk_libm(q, prefix, posts, axes, joint, scale, offset, out)
            return out

        def scalars(q=q, out=out):
            V = (q[:, joint] * scale + offset).T
            fk_scalars(np.cos(V), np.sin(V), prefix, posts, axes, out)
            return out

        ref = robot.fk(q)[:, :3]
        for f in (libm, scalars):
            err = np.abs(f() - ref).max()
            if err > 1e-12:
                raise SystemExit(f"kernel disagrees with Robot.fk by {err:.1e}")
        t = interleaved({"numpy": lambda q=q: robot.fk(q), "libm": libm, "scalars": scalars},
                        rounds=a.rounds)
        ns = {k: t.median(k, cpu=True) / N * 1e9 for k in ("numpy", "libm", "scalars")}
        best = ns["numpy"] / min(ns["libm"], ns["scalars"])
        print(f"{N:>8}{ns['numpy']:>12.0f}{ns['libm']:>17.0f}{ns['scalars']:>23.0f}"
              f"{best:>14.2f}x")


if __name__ == "__main__":
    main()
