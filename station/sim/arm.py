"""The simulated arm (motion model shared by the controller simulator and FakeRobot)."""

from quickhealth.station.hardware.simcontroller import HOME_Q_DEG, Arm

__all__ = ["Arm", "HOME_Q_DEG"]
