"""Non-geometric joint terms: the link does not sit where its encoder says.

A :class:`~kincal.measure.joints.deflection.JointDeflection` wraps any measurement
block and adds ``q_eff = q + c * u`` per joint: compliance under gravity
(:mod:`~kincal.measure.joints.compliance`, ``u = tau(q)``) and hysteresis / backlash
(:mod:`~kincal.measure.joints.hysteresis`, ``u = d``, the approach direction).
:mod:`~kincal.measure.joints.terms` parses ``--joint-model`` and wraps blocks.

Part of the measure layer: imports :mod:`kincal.measure.base`, :mod:`kincal.robots`.
"""
