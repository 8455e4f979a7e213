"""The per-pose loop of one run: move, settle, pan, capture, journal; the 7D measurement in a
worker thread while the arm moves on; the instrument self-check."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ...identify.errors import HardwareError, InputError
from ...vision.markers import Box
from ...vision.pose7d import Rejection, measure_stereo, search_boxes
from ..formats.journal import Captured, Failed, Measured, Record, SelfCheck
from ..fsio import fsync_dir
from ..hardware.cameras import Image
from ..hardware.robot import Leg
from ..station import Station
from .capture import camera_record, exposure_report, measure_frame, measured_record, quick_check
from .exposure import search_exposure
from .journal import Journal, JournalState, write_bytes_atomic
from .progress import Progress, ProgressFn, ProgressKind
from .settings import RunSettings
from .settle import wait_settled

if TYPE_CHECKING:  # types only: the planner loads the collision library
    from ..planning.planfile import Plan, PlanPose

U8 = NDArray[np.uint8]


def plan_speed(plan: Plan, leg: Leg) -> dict[str, float]:
    """The plan's speed and acceleration for a ``leg`` (``robot.move``'s keywords)."""
    mo = plan.motion
    if leg is Leg.JOINT:
        return {"speed": mo.joint_speed, "accel": mo.joint_accel}
    return {"speed": mo.linear_speed, "accel": mo.linear_accel}


class PoseRunner:
    """The per-pose work of :func:`~.loop.run_plan` and its measurement worker."""

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
        self.exposure_search: dict[str, Any] | None = None
        self.exposure_logged = False

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
        leg = Leg(pose.leg)
        self.emit(ProgressKind.MOVE, pose.index, pose.name)
        t0 = time.monotonic()
        t_start = time.time() - self.t_epoch
        s.robot.move(pose.q, leg, **plan_speed(self.plan, leg))
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
        if self.exposure_search is None:
            self.exposure_search = search_exposure(s, T_pred)
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
        joints = s.robot.reader().joint_sensors()  # temperatures and torques at the pose
        images = [f"images/{pose.index:04d}_{pose.name}_{side}.png" for side in "LR"]
        t_capture = time.time() - (time.monotonic() - frame.time) - self.t_epoch
        search = search_boxes(s.camera.rig, T_pred, s.target)
        timing = {"move": t1 - t0, "settle": t2 - t1, "pan": t3 - t2, "capture": td - t3,
                  "start": t_start}  # fmt: skip
        camera = camera_record(frame, exposure_report(s, frame, T_pred, s.target))
        if self.exposure_search and not self.exposure_logged:
            camera["exposure_search"] = self.exposure_search
            self.exposure_logged = True
        self.append(Captured(
            pose.index, pose.name, q_read, pan, t_capture, tuple(images),
            q_cmd=pose.q, attempts=attempt, markers=counts, search=search, timing=timing,
            camera=camera, joint_temp=joints.temperature, joint_torque=joints.torque,
        ))  # fmt: skip
        te = time.monotonic()
        self.tick("journal_s", te - td)
        # Images are written (atomically) and measured by the worker while the arm moves on;
        # a capture whose images never reached the disk is revisited on resume.
        self.submit_measure(
            pose.index, pose.name, frame.left, frame.right, pan, search, write=images,
            bits=frame.bits,
        )  # fmt: skip
        verdict = camera["exposure"]["verdict"]
        note = f"attempt {attempt}" + ("" if verdict == "ok" else f"; the target is {verdict}")
        self.emit(ProgressKind.POSE, pose.index, pose.name, "captured", note)

    def write_images(self, names: list[str], left: Image, right: Image) -> None:
        """Both images, each atomically, then the folder entry made durable (PNG keeps a
        10- to 16-bit camera's images losslessly as 16-bit PNG)."""
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
        left: Image,
        right: Image,
        pan: float,
        search: tuple[Box, Box],
        write: list[str] | None = None,
        bits: int = 8,
    ) -> None:
        # At most two poses in flight: the worker never falls far behind the arm.
        while sum(1 for f in self.pending if not f.done()) >= 2:
            time.sleep(0.005)

        def job() -> None:
            try:
                start = time.time() - self.t_epoch
                t_images = 0.0
                if write is not None:
                    t0 = time.monotonic()
                    self.write_images(write, left, right)
                    t_images = time.monotonic() - t0
                    self.tick("images_s", t_images)
                t0 = time.monotonic()
                m = measure_frame(self.s, self.s.target, left, right, search, bits)
                t_measure = time.monotonic() - t0
                self.tick("measure_s", t_measure)
                timing = {"start": start, "end": time.time() - self.t_epoch,
                          "images": t_images, "measure": t_measure}  # fmt: skip
                if isinstance(m, Rejection):
                    rec = Measured(
                        index, name, False, f"{m.reason.value}: {m.detail}", timing=timing
                    )
                else:
                    rec = replace(measured_record(index, name, m, pan), timing=timing)
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
            imgs = [read_image(self.dir / p) for p in rec.images]
            if any(im is None for im in imgs):
                raise InputError(f"{self.dir}: image of pose {rec.name} is missing or unreadable")
            search = rec.search or search_boxes(
                self.s.camera.rig, self.s.predicted_plate(rec.q, rec.pan), self.s.target
            )
            bits = int((rec.camera or {}).get("bits", 8))
            self.submit_measure(i, rec.name, imgs[0], imgs[1], rec.pan, search, bits=bits)
        self.drain()


def read_image(path: Path) -> Image | None:
    """A stored image at its depth (8-bit, or 16-bit PNG/TIFF of a deeper camera)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        return None
    return img  # type: ignore[no-any-return]
