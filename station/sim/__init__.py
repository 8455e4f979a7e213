"""The simulated cell's hardware: a UR controller simulator and a pure-Python fake robot.

Nothing here is imported by the drivers in :mod:`quickhealth.station.hardware`; the drivers
talk to the simulator over the same sockets as to a real controller.
"""
