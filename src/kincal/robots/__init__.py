"""Serial robots: the elementary-transform chain and the files that describe it.

Every serial robot compiles to one sequence of elementary transforms (Rx, Ry, Rz, Tx,
Ty, Tz), each with a named parameter (``theta_offset[2]``, ``d[3]``,
``arm_3_joint.origin.y``, ``base.x``, ``tool.rz``) and, for a joint, the joint
variable (:mod:`~kincal.robots.chain`).  Denavit-Hartenberg, modified DH, Hayati
(:mod:`~kincal.robots.dh`) and URDF (:mod:`~kincal.robots.urdf`) are front ends to it;
:mod:`~kincal.robots.files` reads and writes YAML robot files and holds the built-in
library (``library/``); :mod:`~kincal.robots.gravity` gives static joint torques from
link masses.

Layer rule: imports only :mod:`kincal.errors`, :mod:`kincal.spatial`, :mod:`kincal.io`
and :mod:`kincal.units`.
"""
