"""quickhealth.vision — the 7D camera.

A pure library (no files, clocks, hardware or global state).  Stages:

1. ``camera``     camera model (pinhole + OpenCV distortion) and the stereo rig
2. ``boards``     calibration boards and smart-target descriptions (and the reference target)
3. ``calibrate``  mono/stereo calibration with outlier rejection, uncertainty and a verdict
4. ``markers``    marker detection tuned for far markers, edge-line corner refinement
5. ``pose7d``     one stereo pose of the smart target with its covariance (and its CRB)
6. ``render``     synthetic images for tests, the simulated cell and the demo

``reference`` holds the reference 7D camera design, ``plots`` the calibration report figures.
Formats and figures: docs/vision.md.
"""
