"""Run a plan on the cell: the per-pose loop, pre-flight, self-check, crash-safe journal.

Stages of :func:`run_plan`, in order:

1. **Pre-flight** (:func:`preflight`), no motion before all pass: robot connected, powered,
   safety normal; plan made for this cell and robot; cameras capture images of the
   calibrated size; pan motor answers; disk space for the remaining poses.
2. **Self-check**: the fixed reference marker board is measured (start, and end of the run);
   the drift between the two is the instrument's, not the robot's, and is reported apart.
3. **Poses**, in plan order.  Per pose: move (joint or linear leg); wait until the joint
   stream shows the arm at rest (:func:`wait_settled`, not a fixed sleep); turn the target to
   face the cameras; capture; quick detection check in the predicted image region (retry,
   else record the pose as failed with the reason); write both images atomically; journal
   the capture (fsync).  The full 7D measurement runs in a worker thread while the robot
   moves on, and is journalled when done.
4. **Finish**: measurements.csv (CSV v1, execution order) and run.json from the journal.

A protective stop, a lost connection, a frozen stream or a motor failure stops the run
cleanly: the arm is stopped, every captured pose is kept (and measured), the journal says
why, and the error says what to do.  ``resume=True`` continues: captured but unmeasured poses
are measured from their images, the arm re-approaches the last completed pose (so every
joint approaches the next pose from the same side as in an uninterrupted run), and the loop
goes on from the first pose with no record.  No pose is lost or repeated.

SYNOPSIS
    >>> station = Station.from_cell(cell, robot, motor, camera)          # doctest: +SKIP
    >>> result = run_plan(station, plan, Path("runs/n1"), progress=print)  # doctest: +SKIP
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from ..identify.errors import HardwareError, InputError
from ..identify.measurements import Measurements
from ..identify.robot import builtin_robot
from ..identify.transforms import R_to_rpy, inv_T, log_so3
from ..vision.boards import TargetDescription
from ..vision.markers import Box, detect_markers
from ..vision.pose7d import (
    PoseMeasurement,
    Rejection,
    measure_stereo,
    roi_from_pose,
    search_boxes,
)
from .formats.common import write_text_atomic
from .formats.journal import Captured, Failed, Measured, Record, RecordKind, SelfCheck
from .formats.measurements import write_measurements
from .formats.vision import read_rig, rig_to_json
from .fsio import fsync_dir, remove_stale_temp_files
from .hardware.cameras import OpenCvStereoCamera, StereoCamera, StereoFrame
from .hardware.motor import PanMotor, SerialPanMotor
from .hardware.owner import DeviceOwner, owned
from .hardware.robot import Leg, Robot, RobotReader, UrRobot
from .hardware.target import T_target_plate, reference_board, reference_target, target0_from_plate
from .journal import JOURNAL, SCHEMA, Journal, JournalState, read_journal, write_bytes_atomic
from .planning.cell import load_cell
from .provenance import software_version

if TYPE_CHECKING:  # types only: the planner loads the collision library, a run needs none of it
    from .planning.planfile import Plan, PlanPose

F = NDArray[np.float64]
U8 = NDArray[np.uint8]
log = logging.getLogger(__name__)
DEVICE_CLOSE_TIMEOUT_S = 5.0  # s a device's owner may take to finish its jobs and close it


@dataclass(frozen=True)
class RunSettings:
    """Tunables of a run (SI).

    Attributes
    ----------
    settle_window_s : float
        The joints must stay within ``settle_tol_rad`` for this long (controller time).
    settle_tol_rad : float
        Peak-to-peak joint motion allowed inside the window.
    settle_timeout_s : float
        Longest wait for rest before the run stops.
    capture_attempts : int
        Captures per pose before it is recorded as failed.
    min_markers : int
        Markers each camera must see in the quick check.
    selfcheck_limit_mm, selfcheck_limit_deg : float
        Largest acceptable drift of the self-check board between start and end.
    png_level : int
        PNG compression (0–9); 1 is fast and still halves the size.
    bytes_per_pose : int or None
        Disk needed per pose (None: estimated from the image size).
    """

    settle_window_s: float = 0.15
    settle_tol_rad: float = 2e-5
    settle_timeout_s: float = 10.0
    capture_attempts: int = 3
    min_markers: int = 6
    selfcheck_limit_mm: float = 0.05
    selfcheck_limit_deg: float = 0.02
    png_level: int = 1
    bytes_per_pose: int | None = None
    selfcheck: bool = True


@dataclass
class Station:
    """The cell's hardware and nominal geometry, as a run needs it.

    Attributes
    ----------
    robot, motor, camera :
        Behind :class:`~.hardware.robot.Robot`, :class:`~.hardware.motor.PanMotor`,
        :class:`~.hardware.cameras.StereoCamera`.
    target : TargetDescription
        The smart target's printed plate.
    T_instr_base : ndarray (4, 4)
        Nominal robot base in the instrument frame (for the search regions).
    T_flange_target : ndarray (4, 4)
        Nominal target frame (pan 0) on the flange.
    board : TargetDescription or None
        The self-check board (None: no self-check).
    T_instr_board : ndarray (4, 4) or None
        Its nominal pose (search region).
    cell_name, cell_sha256 : str
        The cell this station is (pre-flight checks the plan against it).
    instrument : str
        For the CSV metadata.
    """

    robot: Robot
    motor: PanMotor
    camera: StereoCamera
    target: TargetDescription
    T_instr_base: F
    T_flange_target: F
    board: TargetDescription | None = None
    T_instr_board: F | None = None
    cell_name: str = ""
    cell_sha256: str = ""
    instrument: str = "stereo camera"
    robot_name: str = ""
    closers: list[Callable[[], None]] = field(default_factory=list)

    def __post_init__(self) -> None:
        # One owner per device: the run, the pre-flight and the TUI's polls all go through a
        # worker thread and its queue (the robot's owner is its client process).
        self.motor = owned(self.motor, "pan motor")
        self.camera = owned(self.camera, "stereo camera")

    def predicted_plate(self, q: F, pan: float) -> F:
        """Nominal ``T_instr_plate`` at joints ``q`` and pan angle ``pan``."""
        return (
            self.T_instr_base @ self.robot.model.fk(q) @ self.T_flange_target @ T_target_plate(pan)
        )

    def close(self) -> None:
        """Release all hardware (robot last: it stops the arm).

        The pan motor and the camera are closed by their owners' workers, never from here: a
        worker still inside its device after :data:`DEVICE_CLOSE_TIMEOUT_S` leaves the device
        open (a warning says which), and a closer that would close such a device directly
        (``motor.close`` in ``closers``) is skipped."""
        owners = [d for d in (self.motor, self.camera) if isinstance(d, DeviceOwner)]
        for dev in owners:
            try:
                closed = dev.close(DEVICE_CLOSE_TIMEOUT_S)
            except Exception as exc:  # noqa: BLE001 - keep closing the rest
                log.warning("closing the %s failed: %s", dev.name, exc)
                continue
            if not closed:
                inside = dev.busy()
                log.warning(
                    "the %s is still inside %s() after %.0f s: left open (its owner thread "
                    "alone may touch it; the process exit releases it)",
                    dev.name,
                    inside[0] if inside else "a call",
                    DEVICE_CLOSE_TIMEOUT_S,
                )
        for f in reversed(self.closers):
            if any(getattr(f, "__self__", None) is dev.device for dev in owners):
                continue  # that device was closed by its owner (or is left to it)
            try:
                f()
            except Exception:  # noqa: BLE001 - keep closing the rest
                pass
        self.closers.clear()


class ProgressKind(StrEnum):
    """What a :class:`Progress` event is about (the value is what ``quickhealth run`` prints)."""

    PREFLIGHT = "preflight"
    SELFCHECK = "selfcheck"
    RESUME = "resume"
    MOVE = "move"
    POSE = "pose"
    MEASURED = "measured"
    STOP = "stop"
    DONE = "done"


@dataclass(frozen=True)
class Progress:
    """What the run is doing, for progress bars and the TUI.

    ``kind``: a :class:`ProgressKind`.  ``index`` is the 1-based plan index (0 when not about
    a pose).
    """

    kind: ProgressKind
    index: int
    n_poses: int
    name: str = ""
    status: str = ""
    message: str = ""


ProgressFn = Callable[[Progress], None]


@dataclass(frozen=True)
class RunResult:
    """Outcome of :func:`run_plan`."""

    run_dir: Path
    n_poses: int
    n_measured: int
    n_failed: int
    stopped: str | None  # the reason when the run stopped early
    selfcheck_drift_mm: float | None
    selfcheck_drift_deg: float | None
    selfcheck_ok: bool | None
    measurements: Path | None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Every pose has a record."""
        return self.stopped is None


class PoseSequence(Protocol):
    """Which pose a run visits next: the plan's loop order, or a choice made as the data come
    in (the quick check, :mod:`.services.checking`).

    ``order`` is how measurements.csv orders the poses: ``"plan"`` (plan index) or
    ``"capture"`` (the order they were captured in: the execution order of a sequence that
    chooses).  With ``wait_for_measurements`` every pose's 7D measurement is journalled
    before :meth:`next_pose` is asked.
    """

    order: str
    wait_for_measurements: bool

    def next_pose(self, state: JournalState) -> PlanPose | None:
        """The next pose (its ``leg`` says how to move there), or None: the run is done."""
        ...

    def resume_pose(self, state: JournalState) -> PlanPose | None:
        """The pose to re-approach (joint leg) before resuming, so every joint approaches the
        next pose from the side it would have in an uninterrupted run; None: nowhere."""
        ...

    def finish(self, state: JournalState) -> tuple[F, Leg] | None:
        """Where the arm goes after the last pose, and how (None: it stays)."""
        ...


class PlanOrder:
    """The plan's fixed loop: every pose with no record, in plan order, then back home."""

    order = "plan"
    wait_for_measurements = False

    def __init__(self, plan: Plan, done: set[int]) -> None:
        self.plan = plan
        self.todo = [p for p in plan.poses if p.index not in done]
        self.first = self.todo[0].index if self.todo else None
        self.pos = 0

    def next_pose(self, state: JournalState) -> PlanPose | None:
        if self.pos >= len(self.todo):
            return None
        self.pos += 1
        return self.todo[self.pos - 1]

    def resume_pose(self, state: JournalState) -> PlanPose | None:
        if self.first is None:
            return None
        before = [p for p in self.plan.poses if p.index < self.first]
        return before[-1] if before else None

    def finish(self, state: JournalState) -> tuple[F, Leg] | None:
        home = getattr(self.plan, "home", None)
        return None if home is None else (home, Leg(self.plan.return_leg))


# ---------------------------------------------------------------------------------------
# Settle detection
# ---------------------------------------------------------------------------------------


def is_settled(t: F, Q: F, window_s: float, tol_rad: float, min_samples: int = 5) -> bool:
    """True when the last ``window_s`` of samples ``(t, Q)`` stay within ``tol_rad`` peak to peak.

    Parameters
    ----------
    t : ndarray (m,), s
        Sample times (controller clock, increasing).
    Q : ndarray (m, n), rad
    """
    if len(t) < min_samples or t[-1] - t[0] < window_s:
        return False
    sel = t >= t[-1] - window_s
    if sel.sum() < min_samples:
        return False
    W = Q[sel]
    return bool(np.all(W.max(0) - W.min(0) <= tol_rad))


def wait_settled(
    reader: RobotReader,
    q_target: F,
    settings: RunSettings,
    *,
    poll_s: float | None = None,
) -> tuple[F, float]:
    """Wait until the joint stream shows the arm at rest at ``q_target``.

    Returns the mean joints over the settled window (the recorded reading) and the time
    waited (s).  Raises HardwareError when the arm stays in motion past the timeout or rests
    away from its target.
    """
    if poll_s is None:  # half the stream's sample period (125 Hz on a CB3)
        poll_s = 0.5 * float(getattr(reader, "sample_period", 0.008))
    t0 = time.monotonic()
    ts: deque[float] = deque()
    qs: deque[F] = deque()
    last_t = -math.inf
    while True:
        s = reader.sample()
        if s.t > last_t:
            last_t = s.t
            ts.append(s.t)
            qs.append(s.q)
            while len(ts) > 2 and ts[-1] - ts[1] > settings.settle_window_s:
                ts.popleft()
                qs.popleft()
            T = np.fromiter(ts, float)
            Q = np.array(qs)
            if is_settled(T, Q, settings.settle_window_s, settings.settle_tol_rad):
                qm = Q[T >= T[-1] - settings.settle_window_s].mean(0)
                if np.max(np.abs(qm - q_target)) > 1e-3:
                    raise HardwareError(
                        f"the arm came to rest {np.degrees(np.max(np.abs(qm - q_target))):.3f}° "
                        "away from its target: check the robot, then rerun with --resume"
                    )
                return qm, time.monotonic() - t0
        if time.monotonic() - t0 > settings.settle_timeout_s:
            raise HardwareError(
                f"the arm did not come to rest within {settings.settle_timeout_s:.0f} s "
                "(vibration? a loose tool?): check the robot, then rerun with --resume"
            )
        time.sleep(poll_s)


# ---------------------------------------------------------------------------------------
# Detection check and measurement
# ---------------------------------------------------------------------------------------


def quick_check(
    station: Station, frame: StereoFrame, T_pred: F, target: TargetDescription, min_markers: int
) -> tuple[bool, str, tuple[int, int]]:
    """Markers of ``target`` found in each image's predicted region: (ok, reason, counts)."""
    rig = station.camera.rig
    counts = []
    ids = set(int(i) for i in target.ids)
    for cam, img, T in (
        (rig.left, frame.left, T_pred),
        (rig.right, frame.right, rig.T_right_left @ T_pred),
    ):
        roi = roi_from_pose(cam, T, target, margin=0.5)
        det = detect_markers(img, target.dictionary, roi=roi)
        counts.append(sum(1 for i in det.ids if int(i) in ids))
    c = (counts[0], counts[1])
    if min(c) >= min_markers:
        return True, "", c
    return (
        False,
        f"target not detected ({c[0]} markers in the left image, {c[1]} in the right, "
        f"need {min_markers})",
        c,
    )


def measure_frame(
    station: Station, target: TargetDescription, left: U8, right: U8, search: tuple[Box, Box]
) -> PoseMeasurement | Rejection:
    """Full 7D measurement of one stereo pair (the vision library), searched first in the
    boxes ``search`` (px) that the capture record keeps."""
    return measure_stereo(station.camera.rig, target, left, right, roi_hint=search)


def _measured(index: int, name: str, meas: PoseMeasurement, pan: float) -> Measured:
    """The journal record of a measured pose: the target frame at pan 0 with uncertainties."""
    T0 = target0_from_plate(meas.T_left_target, pan)
    m0 = PoseMeasurement(T0, meas.cov, meas.rms_px, meas.n_corners, meas.n_outliers)
    return Measured(
        index,
        name,
        True,
        position=m0.position,
        rpy=m0.rpy,
        sigma_pos=m0.sigma_pos,
        sigma_rpy=m0.sigma_rpy,
        rms_px=meas.rms_px,
        n_corners=tuple(meas.n_corners),
        n_outliers=meas.n_outliers,
    )


# ---------------------------------------------------------------------------------------
# Pre-flight
# ---------------------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------


class _Runner:
    def __init__(
        self,
        station: Station,
        plan: Plan,
        run_dir: Path,
        settings: RunSettings,
        progress: ProgressFn | None,
        cancel: threading.Event | None,
    ) -> None:
        self.s = station
        self.plan = plan
        self.dir = run_dir
        self.cfg = settings
        self.progress = progress or (lambda p: None)
        self.cancel = cancel or threading.Event()
        self.n = len(plan.poses)
        self.jlock = threading.Lock()
        self.journal = Journal(run_dir)
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="measure")
        self.pending: list[Future[None]] = []
        self.worker_error: BaseException | None = None
        self.t_epoch = time.time()
        self.timings: dict[str, list[float]] = {}

    def tick(self, key: str, dt: float) -> None:
        self.timings.setdefault(key, []).append(dt)

    def emit(
        self,
        kind: ProgressKind,
        index: int = 0,
        name: str = "",
        status: str = "",
        message: str = "",
    ) -> None:
        self.progress(Progress(kind, index, self.n, name, status, message))

    def append(self, rec: Record) -> None:
        with self.jlock:
            self.journal.append(rec)

    # -- self-check ----------------------------------------------------------------------
    def selfcheck(self, phase: str) -> SelfCheck | None:
        s = self.s
        if not self.cfg.selfcheck or s.board is None or s.T_instr_board is None:
            return None
        frame = s.camera.capture()
        m = measure_stereo(s.camera.rig, s.board, frame.left, frame.right, roi_hint=s.T_instr_board)
        if isinstance(m, Rejection):
            rec = SelfCheck(phase, False, f"{m.reason.value}: {m.detail}")
        else:
            rec = SelfCheck(
                phase,
                True,
                T_instr_board=m.T_left_target,
                sigma_pos=m.sigma_pos,
                rms_px=m.rms_px,
                time_s=time.time() - self.t_epoch,
            )
        self.append(rec)
        self.emit(
            ProgressKind.SELFCHECK,
            status="ok" if rec.ok else "failed",
            message=f"self-check ({phase})",
        )
        return rec

    # -- one pose --------------------------------------------------------------------------
    def do_pose(self, pose: PlanPose) -> None:
        s, cfg = self.s, self.cfg
        mo = self.plan.motion
        leg = Leg(pose.leg)
        speed, accel = (
            (mo.joint_speed, mo.joint_accel)
            if leg is Leg.JOINT
            else (mo.linear_speed, mo.linear_accel)
        )
        self.emit(ProgressKind.MOVE, pose.index, pose.name)
        t0 = time.monotonic()
        s.robot.move(pose.q, leg, speed=speed, accel=accel)
        t1 = time.monotonic()
        s.motor.move_to(pose.pan, wait=False)  # turns while the arm settles
        q_read, _ = wait_settled(s.robot.reader(), pose.q, cfg)
        t2 = time.monotonic()
        pan = s.motor.move_to(pose.pan, wait=True)
        t3 = time.monotonic()
        self.tick("move_s", t1 - t0)
        self.tick("settle_s", t2 - t1)
        self.tick("pan_wait_s", t3 - t2)
        T_pred = s.predicted_plate(q_read, pan)
        reason = ""
        attempt = 0
        while attempt < cfg.capture_attempts:
            attempt += 1
            ta = time.monotonic()
            frame = s.camera.capture()
            tb = time.monotonic()
            ok, reason, counts = quick_check(s, frame, T_pred, s.target, cfg.min_markers)
            tc = time.monotonic()
            self.tick("capture_s", tb - ta)
            self.tick("check_s", tc - tb)
            if ok:
                break
        else:
            self.append(Failed(
                pose.index, pose.name, f"{reason} after {cfg.capture_attempts} captures",
                q=q_read, pan=pan, time_s=time.time() - self.t_epoch,
            ))  # fmt: skip
            self.emit(ProgressKind.POSE, pose.index, pose.name, "failed", reason)
            return
        td = time.monotonic()
        images = [f"images/{pose.index:04d}_{pose.name}_{side}.png" for side in "LR"]
        t_capture = time.time() - (time.monotonic() - frame.time) - self.t_epoch
        search = search_boxes(s.camera.rig, T_pred, s.target)
        timing = {"move": t1 - t0, "settle": t2 - t1, "pan": t3 - t2, "capture": td - t3}
        self.append(Captured(
            pose.index, pose.name, q_read, pan, t_capture, tuple(images),
            q_cmd=pose.q, attempts=attempt, markers=counts, search=search, timing=timing,
        ))  # fmt: skip
        te = time.monotonic()
        self.tick("journal_s", te - td)
        # Images are written (atomically) and measured by the worker while the arm moves on;
        # a capture whose images never reached the disk is revisited on resume.
        self.submit_measure(
            pose.index, pose.name, frame.left, frame.right, pan, search, write=images
        )
        self.emit(ProgressKind.POSE, pose.index, pose.name, "captured", f"attempt {attempt}")

    def write_images(self, names: list[str], left: U8, right: U8) -> None:
        """Both images, each atomically, then the folder entry made durable."""
        for name, img in zip(names, (left, right), strict=True):
            ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, self.cfg.png_level])
            if not ok:
                raise HardwareError("cannot encode an image as PNG")
            write_bytes_atomic(self.dir / name, buf.tobytes(), sync_dir=False)
        fsync_dir(self.dir / "images")

    def submit_measure(
        self,
        index: int,
        name: str,
        left: U8,
        right: U8,
        pan: float,
        search: tuple[Box, Box],
        write: list[str] | None = None,
    ) -> None:
        # At most two poses in flight: the worker never falls far behind the arm.
        while sum(1 for f in self.pending if not f.done()) >= 2:
            time.sleep(0.005)

        def job() -> None:
            try:
                if write is not None:
                    t0 = time.monotonic()
                    self.write_images(write, left, right)
                    self.tick("images_s", time.monotonic() - t0)
                t0 = time.monotonic()
                m = measure_frame(self.s, self.s.target, left, right, search)
                self.tick("measure_s", time.monotonic() - t0)
                if isinstance(m, Rejection):
                    rec = Measured(index, name, False, f"{m.reason.value}: {m.detail}")
                else:
                    rec = _measured(index, name, m, pan)
                self.append(rec)
                status = "measured" if rec.ok else "failed"
                self.emit(ProgressKind.MEASURED, index, name, status, rec.reason)
            except BaseException as exc:  # noqa: BLE001 - reported by the main loop
                self.worker_error = exc

        self.pending.append(self.pool.submit(job))

    def drain(self) -> None:
        for f in self.pending:
            f.result()
        self.pending.clear()
        if self.worker_error is not None:
            err, self.worker_error = self.worker_error, None
            raise err

    def remeasure(self, state: JournalState, unmeasured: list[int]) -> None:
        for i in unmeasured:
            rec = state.captured[i]
            imgs = [cv2.imread(str(self.dir / p), cv2.IMREAD_GRAYSCALE) for p in rec.images]
            if any(im is None for im in imgs):
                raise InputError(f"{self.dir}: image of pose {rec.name} is missing or unreadable")
            search = rec.search or search_boxes(
                self.s.camera.rig, self.s.predicted_plate(rec.q, rec.pan), self.s.target
            )
            self.submit_measure(i, rec.name, imgs[0], imgs[1], rec.pan, search)
        self.drain()


CALIBRATION = "calibration.json"


def write_calibration(station: Station, run_dir: Path) -> None:
    """The run folder's ``calibration.json``: the stereo calibration of the cameras that take
    its images (the simulated cell's scaled cameras too), so ``quickhealth vision measure
    RUN`` measures the stored images again with the cameras that took them.  A folder that
    already has one (a resumed run) keeps it."""
    cal = run_dir / CALIBRATION
    rig = getattr(station.camera, "rig", None)
    if rig is None or cal.exists():
        return
    doc = rig_to_json(rig, note=f"the cameras of this run: {station.instrument}")
    write_bytes_atomic(cal, (json.dumps(doc, indent=1) + "\n").encode("utf-8"))


def run_plan(
    station: Station,
    plan: Plan,
    run_dir: Path | str,
    *,
    resume: bool = False,
    settings: RunSettings = RunSettings(),
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    sequence: PoseSequence | None = None,
    start_extra: dict[str, object] | None = None,
    check_resume: Callable[[JournalState], None] | None = None,
) -> RunResult:
    """Execute ``plan`` on ``station`` into ``run_dir`` (see the module docstring).

    Parameters
    ----------
    station : Station
    plan : Plan
        From ``quickhealth.station.planning.load_plan``.
    run_dir : path
        The run folder (created; must not hold a journal unless ``resume``).
    resume : bool
        Continue the interrupted run in ``run_dir``.
    progress : callable, optional
        Called with a :class:`Progress` for every step (from the run's threads).
    cancel : threading.Event, optional
        Set it to stop after the current pose (the run can be resumed).
    sequence : PoseSequence, optional
        Which pose comes next (default :class:`PlanOrder`: the plan's loop).
    start_extra : dict, optional
        More keys for the journal's start record (e.g. what kind of run it is).
    check_resume : callable, optional
        Called with the interrupted run's journal before resuming; raises InputError when
        the folder holds another kind of run.

    Returns
    -------
    RunResult
        Also when the run stopped on a hardware fault (``stopped`` says why); the same
        message is then raised as HardwareError by the command line.

    Raises
    ------
    InputError
        The run folder does not fit (existing run without ``resume``, another plan …).
    HardwareError
        Pre-flight failed (nothing moved).
    """
    run_dir = Path(run_dir)
    jpath = run_dir / JOURNAL
    if resume:
        if not jpath.is_file():
            raise InputError(f"{run_dir}: no interrupted run to resume (no {JOURNAL})")
        state = read_journal(jpath)
        if state.start is None:
            raise InputError(f"{jpath}: empty journal")
        if state.ended:
            raise InputError(f"{run_dir}: this run is already complete; nothing to resume")
        if state.start.get("plan_hash") != plan.hash:
            raise InputError(
                f"{jpath}: the interrupted run used plan {state.start.get('plan_hash', '?')[:19]}…, "
                f"not {plan.hash[:19]}…: resume with the same plan.json"
            )
        if check_resume is not None:
            check_resume(state)
    else:
        if jpath.exists():
            raise InputError(
                f"{run_dir}: already holds a run; add --resume to continue it or choose a new folder"
            )
        run_dir.mkdir(parents=True, exist_ok=True)
        state = JournalState()
    (run_dir / "images").mkdir(exist_ok=True)
    write_calibration(station, run_dir)
    if resume:  # half-written files of the killed run (its images are captured again)
        for folder in (run_dir, run_dir / "images"):
            remove_stale_temp_files(folder)
    r = _Runner(station, plan, run_dir, settings, progress, cancel)
    # A capture counts once its images are on disk (they are written after the record).
    imaged = {
        i for i, rec in state.captured.items() if all((run_dir / p).is_file() for p in rec.images)
    }
    done = imaged | set(state.failed)
    unmeasured = sorted(i for i in imaged if i not in state.measured)
    todo = [p for p in plan.poses if p.index not in done]
    seq: PoseSequence = sequence if sequence is not None else PlanOrder(plan, done)
    lines = preflight(station, plan, run_dir, len(todo), settings, resume=resume)
    for ln in lines:
        r.emit(ProgressKind.PREFLIGHT, status="ok", message=ln)
    r.journal.open(truncate_to=state.valid_bytes if state.truncated_tail else None)
    station.robot.clear_stop()  # starting (or resuming) is the operator's go: moves allowed
    stopped: str | None = None
    try:
        if resume:
            r.t_epoch = float(state.start["epoch"])
            r.append({"type": RecordKind.RESUME, "at_utc": _utc(), "done": len(done),
                      "truncated_tail": state.truncated_tail})  # fmt: skip
            r.emit(ProgressKind.RESUME, message=f"{len(done)} of {r.n} poses done; "
                   f"{len(unmeasured)} to measure from images")  # fmt: skip
            r.remeasure(state, unmeasured)
        else:
            r.append({
                "type": RecordKind.START, "schema": SCHEMA, "run_id": run_dir.name, "plan_hash": plan.hash,
                "plan_source": str(plan.source), "cell": station.cell_name, "cell_sha256": station.cell_sha256,
                "robot": station.robot_name or station.robot.model.name, "n_poses": r.n,
                "started_utc": _utc(), "epoch": r.t_epoch, "software": f"quickhealth {software_version()}",
                "instrument": station.instrument,
                **(start_extra or {}),
            })  # fmt: skip
        r.selfcheck("start" if not resume else "resume")
        if resume and todo:
            last = seq.resume_pose(read_journal(jpath))
            if last is not None:  # re-approach the last completed pose: same approach directions
                mo = plan.motion
                station.robot.move(last.q, Leg.JOINT, speed=mo.joint_speed, accel=mo.joint_accel)
        while True:
            if r.cancel.is_set():
                stopped = "cancelled by the operator; rerun with --resume to continue"
                break
            if seq.wait_for_measurements:
                r.drain()
            pose = seq.next_pose(read_journal(jpath) if seq.wait_for_measurements else state)
            if pose is None:
                break
            r.do_pose(pose)
            if r.worker_error is not None:
                r.drain()
        end = seq.finish(read_journal(jpath)) if stopped is None else None
        if end is not None:  # close the loop: back to the start
            target, leg = end
            mo = plan.motion
            speed, accel = (
                (mo.joint_speed, mo.joint_accel)
                if leg is Leg.JOINT
                else (mo.linear_speed, mo.linear_accel)
            )
            r.emit(ProgressKind.MOVE, message="return to home")
            station.robot.move(target, leg, speed=speed, accel=accel)
    except HardwareError as exc:
        stopped = str(exc)
        try:
            station.robot.stop()
        except HardwareError as stop_exc:  # not confirmed: the arm may still be moving
            stopped = f"{stopped}; {stop_exc}"
    try:
        r.drain()
    finally:
        r.pool.shutdown(wait=True)
    drift = None
    if stopped is None:
        r.selfcheck("end")
        st2 = read_journal(jpath)
        drift = _drift(st2.selfchecks)
        r.append({"type": RecordKind.END, "at_utc": _utc()})
    else:
        r.append({"type": RecordKind.STOP, "reason": stopped, "at_utc": _utc()})
        r.emit(ProgressKind.STOP, message=stopped)
    r.journal.close()
    final = read_journal(jpath)
    meas_path = write_outputs(run_dir, final, plan, station, drift, settings, order=seq.order)
    res = RunResult(
        run_dir=run_dir,
        n_poses=r.n,
        n_measured=sum(1 for m in final.measured.values() if m.ok),
        n_failed=len(final.failed) + sum(1 for m in final.measured.values() if not m.ok),
        stopped=stopped,
        selfcheck_drift_mm=None if drift is None else drift[0],
        selfcheck_drift_deg=None if drift is None else drift[1],
        selfcheck_ok=None
        if drift is None
        else bool(
            drift[0] <= settings.selfcheck_limit_mm and drift[1] <= settings.selfcheck_limit_deg
        ),
        measurements=meas_path,
        timings={k: float(np.mean(v)) for k, v in r.timings.items()},
    )
    r.emit(ProgressKind.DONE, status="stopped" if stopped else "complete",
           message=f"{res.n_measured} measured, {res.n_failed} failed of {res.n_poses}")  # fmt: skip
    return res


def _drift(checks: list[SelfCheck]) -> tuple[float, float] | None:
    """The self-check board's drift between the first and the last good check (mm, deg: the
    run's result and run.json give it so)."""
    ok = [c.T_instr_board for c in checks if c.ok and c.T_instr_board is not None]
    if len(ok) < 2:
        return None
    A, B = ok[0], ok[-1]
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3])) * 1e3
    da = float(np.degrees(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T))))
    return dp, da


def _utc() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def journal_measurements(
    state: JournalState, plan: Plan | None, meta: dict[str, str], *, order: str = "plan"
) -> Measurements | None:
    """The measured poses of a journal as :class:`Measurements`, in execution order: plan
    order (a run of the loop), or with ``order="capture"`` the order the journal recorded
    the captures in (a run whose sequence chose its poses, :class:`PoseSequence`)."""
    ok = [i for i, m in state.measured.items() if m.ok and i in state.captured]
    if order == "capture":
        rank = {i: k for k, i in enumerate(state.captured)}
        idx = sorted(ok, key=rank.__getitem__)
    else:
        idx = sorted(ok)
    if not idx:
        return None
    cap = [state.captured[i] for i in idx]
    mea = [state.measured[i] for i in idx]
    return Measurements(
        q=np.array([c.q for c in cap]),
        pos=np.array([m.position for m in mea]),
        rpy=np.array([m.rpy for m in mea]),
        time=np.array([c.time_s for c in cap]),
        pan=np.array([c.pan for c in cap]),
        sigma_pos=np.array([m.sigma_pos for m in mea]),
        sigma_rpy=np.array([m.sigma_rpy for m in mea]),
        pose_id=tuple(c.name for c in cap),
        meta=meta,
    )


def write_outputs(
    run_dir: Path,
    state: JournalState,
    plan: Plan,
    station: Station,
    drift: tuple[float, float] | None,
    settings: RunSettings,
    *,
    order: str = "plan",
) -> Path | None:
    """measurements.csv and run.json from the journal (atomic writes); ``order`` as
    :func:`journal_measurements`."""
    start = state.start or {}
    meta = {
        "run_id": str(start.get("run_id", run_dir.name)),
        "robot": str(start.get("robot", "")),
        "instrument": str(start.get("instrument", "")),
        "cell": str(start.get("cell", "")),
        "plan_hash": str(start.get("plan_hash", "")),
        "started_utc": str(start.get("started_utc", "")),
        "frame": "target frame at pan 0 (plan convention), instrument = left camera",
    }
    if drift is not None:
        meta["selfcheck_drift_mm"] = f"{drift[0]:.4f}"
        meta["selfcheck_drift_deg"] = f"{drift[1]:.5f}"
    meas = journal_measurements(state, plan, meta, order=order)
    path = None
    if meas is not None:
        path = run_dir / "measurements.csv"
        write_measurements(path, meas)
    summary = {
        "schema": "quickhealth.run/1",
        **meta,
        "n_poses": len(plan.poses),
        "n_captured": len(state.captured),
        "n_measured": 0 if meas is None else meas.n_poses,
        "failed": [
            {"index": i, "name": f.name, "reason": f.reason}
            for i, f in sorted(state.failed.items())
        ]
        + [
            {"index": i, "name": m.name, "reason": m.reason}
            for i, m in sorted(state.measured.items())
            if not m.ok
        ],
        "stopped": state.stops[-1]["reason"] if state.stops and not state.ended else None,
        "complete": state.ended,
        "resumes": state.resumes,
        "selfcheck": {
            "drift_mm": None if drift is None else drift[0],
            "drift_deg": None if drift is None else drift[1],
            "limit_mm": settings.selfcheck_limit_mm,
            "limit_deg": settings.selfcheck_limit_deg,
            "ok": None
            if drift is None
            else drift[0] <= settings.selfcheck_limit_mm
            and drift[1] <= settings.selfcheck_limit_deg,
        },
    }
    write_text_atomic(run_dir / "run.json", json.dumps(summary, indent=1) + "\n")
    return path


def ur_station(
    cell: str,
    robot_ip: str,
    *,
    motor_port: str,
    cameras: tuple[int | str, int | str],
    calibration: str,
) -> Station:
    """A :class:`Station` on real hardware: UR robot, serial pan motor, two OpenCV cameras."""
    c = load_cell(cell)
    rig = read_rig(Path(calibration))
    closers: list[Callable[[], None]] = []
    try:
        arm = builtin_robot(c.robot.name)  # the cell's arm with its own limits; its stream rate
        robot = UrRobot(robot_ip, model=arm, frequency=arm.control_hz or 125.0)
        closers.append(robot.close)
        motor = SerialPanMotor(motor_port)
        closers.append(motor.close)
        camera = OpenCvStereoCamera(cameras[0], cameras[1], rig)
        closers.append(camera.close)
    except BaseException:
        for f in reversed(closers):
            f()
        raise
    return Station(
        robot=robot,
        motor=motor,
        camera=camera,
        target=reference_target(),
        T_instr_base=inv_T(c.T_world_cam_left) @ c.T_world_base,
        T_flange_target=c.T_flange_target,
        board=reference_board(),
        T_instr_board=None,
        cell_name=c.name,
        cell_sha256=c.sha256,
        instrument=f"stereo camera {calibration}",
        closers=closers,
    )


# Keep R_to_rpy/inv_T importable for callers that post-process journals.
__all__ = [
    "PlanOrder",
    "PoseSequence",
    "Progress",
    "RunResult",
    "RunSettings",
    "Station",
    "is_settled",
    "preflight",
    "quick_check",
    "run_plan",
    "wait_settled",
    "journal_measurements",
    "R_to_rpy",
    "inv_T",
]
