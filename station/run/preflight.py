"""Pre-flight: every check before the first motion (nothing moves)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...identify.errors import HardwareError, InputError
from ..station import Station
from .settings import RunSettings

if TYPE_CHECKING:  # types only: the planner loads the collision library
    from ..planning.planfile import Plan


def preflight(
    station: Station,
    plan: Plan,
    run_dir: Path,
    n_remaining: int,
    settings: RunSettings,
    *,
    resume: bool = False,
) -> list[str]:
    """Every check before the first motion; returns the lines passed, raises on the first failure."""
    passed = []
    st = station.robot.status()
    if not st.connected:
        raise HardwareError("pre-flight: robot controller not connected")
    if not st.ready:
        raise HardwareError(
            f"pre-flight: robot not ready ({st.describe()}): power on, release the brakes and "
            "clear any stop on the teach pendant"
        )
    passed.append(f"robot: {st.describe()}")
    model = station.robot.model
    if plan.robot.name != model.name or plan.robot.n_joints != model.n_joints:
        raise InputError(
            f"pre-flight: the plan is for a {plan.robot.name}, the robot is a {model.name}"
        )
    if np.any(plan.robot.q_min < model.q_min - 1e-9) or np.any(
        plan.robot.q_max > model.q_max + 1e-9
    ):
        raise InputError("pre-flight: the plan's joint limits exceed the robot's")
    if station.cell_sha256 and plan.cell_sha256 != station.cell_sha256:
        raise InputError(
            f"pre-flight: the plan was made for cell {plan.cell_name!r} with different "
            f"contents (sha256 {plan.cell_sha256[:12]}…, this cell {station.cell_sha256[:12]}…): "
            "plan again for this cell"
        )
    if not np.allclose(plan.T_flange_target, station.T_flange_target, atol=1e-6):
        raise InputError("pre-flight: the plan's target mount differs from this cell's")
    passed.append(f"plan: {len(plan.poses)} poses for {plan.robot.name} in cell {plan.cell_name}")
    home = getattr(plan, "home", None)
    if home is not None and not resume:
        q = station.robot.joints()
        off = float(np.degrees(np.max(np.abs(q - home))))
        if off > 0.5:
            raise HardwareError(
                f"pre-flight: the robot is {off:.1f}° away from the plan's home position "
                f"{np.degrees(home).round(2).tolist()} deg: jog it there first (the first move "
                "was checked for collisions from home only)"
            )
        passed.append("robot at the plan's home position")
    frame = station.camera.capture()
    for img, cam, side in (
        (frame.left, station.camera.rig.left, "left"),
        (frame.right, station.camera.rig.right, "right"),
    ):
        if (img.shape[1], img.shape[0]) != cam.image_size:
            raise HardwareError(
                f"pre-flight: {side} camera image size {img.shape[::-1]} ≠ calibration {cam.image_size}"
            )
        if float(img.std()) < 1.0:
            raise HardwareError(
                f"pre-flight: the {side} camera image is blank (lens cap? lighting?)"
            )
    passed.append(
        f"cameras: {frame.left.shape[1]}×{frame.left.shape[0]} px, skew {frame.skew * 1e3:.1f} ms"
    )
    station.motor.ping()
    passed.append(f"pan motor: at {math.degrees(station.motor.position()):.2f}°")
    need = n_remaining * (settings.bytes_per_pose or int(frame.left.size * 1.2 * 2)) + 50_000_000
    free = shutil.disk_usage(run_dir).free
    if free < need:
        raise HardwareError(
            f"pre-flight: {free / 1e9:.2f} GB free in {run_dir}, the run needs ≈ {need / 1e9:.2f} GB"
        )
    passed.append(f"disk: {free / 1e9:.1f} GB free, ≈ {need / 1e9:.2f} GB needed")
    return passed
