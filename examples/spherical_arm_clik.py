"""Closed-loop inverse kinematics of a spherical RRP arm along a straight line.

The experiment of the spherical-manipulator report (one of the founding documents).

The arm (standard DH: alpha1 = -90 deg, alpha2 = +90 deg with d2 = 1 m, joint 3
prismatic) starts at q(0) = [0, pi/4, 0.5], i.e. at p_i = [sqrt(2)/4, 1, sqrt(2)/4] m,
and must follow the segment to p_f = [-sqrt(2)/2, sqrt(2)/2, 0.1] m (q_f = [pi/4, 0,
0.1]) in 4 s, with q_dot = J#(q)(p_dot_d + K e), K = 50 I [1/s], Euler steps of 2 ms and
a quintic timing law.

What happens: the arm can never come closer than d2 to its first axis
(rho^2 = x^2 + y^2 = d2^2 + (s2 d3)^2), and the wall rho = d2 is where theta2 = 0 and the
position Jacobian is singular (|det J| = d3^2 |s2|).  The straight line dips inside
that cylinder for s in (0.103, 1), down to rho = 0.870 m, and ends on its wall at p_f.

* J^-1 follows the line until it meets the wall (t ~ 1.0 s); joint 2's velocity climbs
  as theta2 -> 0, then the inversion of a near-singular J sends the arm flailing
  (velocities of 1e6-1e9 rad/s) while the target is out of reach.
* Damped least squares (k = 0.1 m) keeps every joint velocity below 2 rad/s, slides along
  the wall (at most 0.130 m from the line, which is the least any method can do) and
  rejoins the line at p_f with an error below 1e-6 m.

Run:  python examples/spherical_arm_clik.py [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from kincal.motion.clik import (
    SPHERICAL_ARM_P_F,
    SPHERICAL_ARM_P_I,
    SPHERICAL_ARM_Q0,
    SPHERICAL_ARM_QF,
    plot_clik,
    run_spherical_arm,
    spherical_arm_robot,
)
from kincal.motion.ik_closed_form import ik_spherical_rrp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("spherical_arm_out"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    robot = spherical_arm_robot()
    print("p(q0) =", robot.fk(SPHERICAL_ARM_Q0)[:3, 3], " p_i =", SPHERICAL_ARM_P_I)
    print("p(qf) =", robot.fk(SPHERICAL_ARM_QF)[:3, 3], " p_f =", SPHERICAL_ARM_P_F)
    cf = ik_spherical_rrp(robot, SPHERICAL_ARM_P_F)
    print("closed-form IK of p_f (branches):", np.round(cf.q[0], 6).tolist())

    runs = [run_spherical_arm("inverse"), run_spherical_arm("dls", damping=0.1),
            run_spherical_arm("adaptive", damping=0.2, threshold=0.1)]
    for r in runs:
        r.to_csv(args.out / f"clik_{r.method}.csv")
        s = r.summary()
        print(f"{r.method:9s} final |e| = {s['final_position_error_m']:.3e} m, "
              f"max distance from the line = {s['max_path_deviation_m']:.4g} m, "
              f"max |theta2_dot| = {s['max_abs_theta2_dot_rad_s']:.4g} rad/s")
    inv, dls = runs[0], runs[1]
    print(f"peak |theta2_dot| ratio J^-1 / DLS = "
          f"{np.abs(inv.qd[:, 1]).max() / np.abs(dls.qd[:, 1]).max():.3g}")
    plot_clik(runs, args.out / "spherical_arm_clik.png",
              title="spherical arm: J^-1, DLS and adaptive damping along p_i -> p_f")
    print(f"CSV and plot written to {args.out}/")


if __name__ == "__main__":
    main()
