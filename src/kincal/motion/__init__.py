"""Motion of a serial robot: inverse kinematics, closed forms, trajectories, CLIK.

* :mod:`~kincal.motion.ik` - batched numerical IK with a reason for every failure
  (its problem in :mod:`~kincal.motion.ik_problem`, starts in
  :mod:`~kincal.motion.joint_limits` and :mod:`~kincal.motion.ik_starts`);
* :mod:`~kincal.motion.ik_closed_form` - every branch of the PUMA 560, SCARA and
  spherical-arm closed forms;
* :mod:`~kincal.motion.timing`, :mod:`~kincal.motion.paths`,
  :mod:`~kincal.motion.trajectory` - timing laws and joint / line / arc paths;
* :mod:`~kincal.motion.clik` - closed-loop inverse kinematics along a path.

Layer rule: imports :mod:`kincal.robots` and the shared root modules, nothing above.
"""
