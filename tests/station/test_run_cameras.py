"""A run seen through a real camera SDK: pypylon's emulated cameras on the in-process
simulated cell.  The journal names the cameras, keeps 12-bit images losslessly and measures
them at their depth; a camera fault (unplugged, a missing trigger edge) stops the run in one
line and ``resume`` continues with no pose lost or measured twice; faults a camera recovers
from (a dropped frame, a pair out of step, a reboot) never stop it."""

from __future__ import annotations

import dataclasses
import json
import math
import os

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon lists its cameras

import cv2
import numpy as np
import pytest
import qh_station_plan as _station_plan

from quickhealth.station.cli import main
from quickhealth.station.formats import read_measurements
from quickhealth.station.hardware.cameras.config import choose
from quickhealth.station.hardware.motor import SerialPanMotor
from quickhealth.station.hardware.target import T_target_plate
from quickhealth.station.planning import load_cell, load_plan
from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal
from quickhealth.station.run.loop import run_plan
from quickhealth.station.run.settings import RunSettings
from quickhealth.station.sim.cameras import SimStereoCamera, scaled_rig
from quickhealth.station.sim.cell import emulated_cameras, station_in_world
from quickhealth.station.sim.fake_robot import FakeRobot
from quickhealth.station.sim.motor_emulator import MotorEmulator
from quickhealth.station.sim.world import build_world
from quickhealth.vision.render import Imaging

SETTINGS = RunSettings(capture_attempts=2)


@pytest.fixture(scope="module")
def world():  # type: ignore[no-untyped-def]
    return build_world("reference", twin_seed=1)


@pytest.fixture(scope="module")
def plan(tmp_path_factory):  # type: ignore[no-untyped-def]
    return load_plan(_station_plan.plan_file(tmp_path_factory.getbasetemp()))


class PylonCell:
    """FakeRobot, the pan-motor emulator, and the rendered scene served by pypylon's
    emulated cameras through the pylon backend (or Aravis' fake cameras through aravis)."""

    def __init__(self, world, bits: int = 8, exposure: str = "", backend: str = "pylon") -> None:  # type: ignore[no-untyped-def]
        cell = load_cell("reference")
        self.robot = FakeRobot(cell.home, time_scale=25)
        self.emu = MotorEmulator(speed_deg_s=2000).start()
        self.motor = SerialPanMotor(self.emu.port, timeout=0.05, retries=2)

        def scene():  # type: ignore[no-untyped-def]
            q = self.robot.arm.actual(self.robot.now())
            pan = math.radians(self.emu.position_deg())
            T = world.T_instr_target0(q, self.robot.arm.approach) @ T_target_plate(pan)
            return [(T, world.target)]

        renderer = SimStereoCamera(
            scaled_rig(world.rig, 0.25),
            scene,
            static=[(world.T_instr_board, world.board)],
            imaging=Imaging(bits=bits),
        )
        cfg = dataclasses.replace(
            choose(None, backend), pixel_format=f"Mono{bits}", timeout_s=0.3, attempts=3
        )
        if exposure:
            spec = dict(exposure_us=float(exposure))
            cfg = dataclasses.replace(
                cfg,
                left=dataclasses.replace(cfg.left, **spec),
                right=dataclasses.replace(cfg.right, **spec),
            )
        self.camera = emulated_cameras(cfg, renderer)
        self.feed = self.camera._prepare
        self.station = station_in_world(
            cell,
            world,
            self.robot,
            self.motor,
            self.camera,
            closers=[self.emu.stop, self.motor.close],
        )

    def close(self) -> None:
        self.station.close()


def test_a_12_bit_run_through_emulated_pylon_cameras(world, plan, tmp_path) -> None:  # type: ignore[no-untyped-def]
    fc = PylonCell(world, bits=12)  # exposure left to the search
    fc.camera.set_exposure(4000.0)  # the cameras start far too short: the search finds it
    try:
        res = run_plan(fc.station, dataclasses.replace(plan, poses=plan.poses[:3]), tmp_path / "r",
                       settings=SETTINGS)  # fmt: skip
    finally:
        fc.close()
    assert res.complete and res.n_measured == 3
    run = tmp_path / "r"
    st = read_journal(run / JOURNAL)
    start = st.start
    assert [c["serial"] for c in start["cameras"]] == ["0815-0000", "0815-0001"]
    assert all(c["vendor"] == "Basler" and c["firmware"] for c in start["cameras"])
    assert json.loads((run / "run.json").read_text())["cameras"] == start["cameras"]
    first = st.captured[1].camera
    assert first is not None and first["bits"] == 12 and first["trigger"] == "software"
    search = first["exposure_search"]
    assert search["steps"][0]["exposure_us"] == 4000.0 and search["steps"][0]["white"] < 0.5
    assert abs(search["white"] - 0.8) <= 0.06  # 80 % of full scale, no clipping
    for rec in st.captured.values():
        assert rec.camera["exposure"]["verdict"] == "ok"
        assert rec.camera["left"]["exposure_us"] == search["exposure_us"]
        for name in rec.images:  # 16-bit PNG holding the 12 bits
            img = cv2.imread(str(run / name), cv2.IMREAD_UNCHANGED)
            assert img.dtype == np.uint16 and 2000 < img.max() <= 4095
    m = read_measurements(run / "measurements.csv")
    T = world.twin.true_pose(m.q)
    err = np.linalg.norm(m.pos - T[:, :3, 3], axis=1)
    assert np.all(err < 5 * np.linalg.norm(m.sigma_pos, axis=1) + 2e-5)
    # measured again offline from the stored 16-bit PNGs, at their depth: the same numbers
    assert main(["vision", "measure", str(run), "--out", str(tmp_path / "again.csv")]) == 0
    again = read_measurements(tmp_path / "again.csv")
    assert np.max(np.abs(again.pos - m.pos)) < 1e-9
    # the loop did not wait for vision: pose k was measured while the arm went on to k+1
    for k in (1, 2):
        assert st.measured[k].timing["start"] < st.captured[k + 1].time_s
    timing = json.loads((run / "run.json").read_text())["timing"]
    assert timing["pairs"] == 2 and timing["done_before_next_capture"] >= 1


def test_camera_faults_stop_cleanly_and_the_run_resumes(world, plan, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A camera unplugged, then a missing trigger edge: each stops the run in one line with
    the pose not given up; the camera plugged back in (the trigger cable seated), ``resume``
    continues; in the end every pose is captured once and measured."""
    p = dataclasses.replace(plan, poses=plan.poses[:3])
    fc = PylonCell(world, exposure="10000")
    run_dir = tmp_path / "r"
    try:
        for fault, at, resume in (("unplug", 1, False), ("timeout", 2, True)):

            def progress(ev, fault=fault, at=at):  # type: ignore[no-untyped-def]
                if ev.kind == "pose" and ev.index == at:
                    fc.feed.inject(fault)

            res = run_plan(fc.station, p, run_dir, resume=resume, settings=SETTINGS,
                           progress=progress)  # fmt: skip
            assert res.stopped is not None and "\n" not in res.stopped, fault
            assert "no good stereo pair" in res.stopped and "--resume" in res.stopped
            st = read_journal(run_dir / JOURNAL)
            assert sorted(st.captured) == list(range(1, at + 1)) and not st.failed
            fc.feed.clear()  # the technician plugs the camera (its trigger cable) back in
        res = run_plan(fc.station, p, run_dir, resume=True, settings=SETTINGS)
    finally:
        fc.close()
    assert res.complete and res.n_measured == 3
    caps = [r["index"] for _, r, _ in iter_records(run_dir / JOURNAL) if r["type"] == "captured"]
    assert sorted(caps) == [1, 2, 3]  # nothing lost, nothing captured twice


def test_faults_a_camera_recovers_from_never_stop_the_run(world, plan, tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = dataclasses.replace(plan, poses=plan.poses[:4])
    fc = PylonCell(world, exposure="10000")
    kinds = iter(["dropped_frame", "out_of_step", "reboot"])
    try:

        def progress(ev):  # type: ignore[no-untyped-def]
            if ev.kind == "pose":
                kind = next(kinds, None)
                if kind is not None:
                    fc.feed.inject(kind)

        fc.feed.reboot_s = 0.2
        res = run_plan(fc.station, p, tmp_path / "r", settings=SETTINGS, progress=progress)
        stats = dict(fc.camera.stats)
    finally:
        fc.close()
    assert res.complete and res.n_measured == 4
    assert stats["dropped"] >= 1 and stats["out_of_step"] >= 1, stats
    st = read_journal(tmp_path / "r" / JOURNAL)
    problems = " ".join(" ".join(r.camera.get("recaptured", [])) for r in st.captured.values())
    assert "dropped" in problems and "out of step" in problems


def test_a_run_through_aravis_fake_cameras(world, plan, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The same loop through Aravis: its fake cameras named in the journal, the poses
    measured within the vision's accuracy of the twin's truth."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
    except (ImportError, ValueError) as exc:
        from qh_required import unavailable

        unavailable(f"Aravis 0.8 with PyGObject is not installed ({exc}): make aravis")
    fc = PylonCell(world, backend="aravis", exposure="10000")
    try:
        res = run_plan(fc.station, dataclasses.replace(plan, poses=plan.poses[:3]), tmp_path / "r",
                       settings=SETTINGS)  # fmt: skip
    finally:
        fc.close()
    assert res.complete and res.n_measured == 3
    st = read_journal(tmp_path / "r" / JOURNAL)
    assert [c["serial"] for c in st.start["cameras"]] == ["QH-SIM-L", "QH-SIM-R"]
    assert all(c["vendor"] == "Aravis" and c["model"] == "Fake" for c in st.start["cameras"])
    m = read_measurements(tmp_path / "r" / "measurements.csv")
    T = world.twin.true_pose(m.q)
    err = np.linalg.norm(m.pos - T[:, :3, 3], axis=1)
    assert np.all(err < 5 * np.linalg.norm(m.sigma_pos, axis=1) + 2e-5)
