"""quickhealth.vision — the 7D camera.

A pure library (no hardware, no global state).  Stages:

1. ``boards``     calibration boards and smart-target descriptions
2. ``calibrate``  stereo calibration with outlier rejection and uncertainty
3. ``markers``    marker detection in an image pair
4. ``pose7d``     one stereo pose of the smart target with its covariance
5. ``render``     synthetic images for tests, the simulated cell and the demo
"""
