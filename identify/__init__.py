"""quickhealth.identify — the assessment: from 7D measurements to a diagnosis.

A pure library: arrays and dataclasses in and out, no files, clocks or hardware.
Stages, in the order the data flows:

1. ``robot``        nominal kinematics, limits, link masses (``RobotModel``)
2. ``measurements`` what the instrument saw, in execution order (``Measurements``)
3. ``errormodel``   the paper's E matrices with Chebyshev series (``ErrorModelSpec``)
4. ``fit``          implicit-loop maximum-likelihood estimation
5. ``select``       BIC order selection
6. ``effects``      physical effects a joint polynomial cannot express
7. ``diagnose``     which effect is missing, and how much it would help
8. ``report``       workspace error, error curves, figures
"""
