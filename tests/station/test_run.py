"""The per-pose loop on the pure-Python fake robot, the pty pan motor and simulated cameras.

Small images (1/4 of the reference sensor) keep these fast; accuracy is checked in the
integration test with the real ur-rtde client (test_run_sim.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading

import numpy as np
import pytest
import qh_station_plan as _station_plan

from quickhealth.station.hardware.motor import SerialPanMotor
from quickhealth.station.hardware.target import T_target_plate
from quickhealth.station.planning import load_cell, load_plan
from quickhealth.station.run.journal import JOURNAL, read_journal
from quickhealth.station.run.loop import run_plan
from quickhealth.station.run.settings import RunSettings
from quickhealth.station.run.settle import is_settled
from quickhealth.station.sim.cameras import SimStereoCamera, scaled_rig
from quickhealth.station.sim.cell import station_in_world
from quickhealth.station.sim.fake_robot import FakeRobot
from quickhealth.station.sim.motor_emulator import MotorEmulator
from quickhealth.station.sim.world import build_world

SETTINGS = RunSettings(capture_attempts=2)


@pytest.fixture(scope="module")
def world():
    return build_world("reference", twin_seed=1)


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return load_plan(_station_plan.plan_file(tmp_path_factory.getbasetemp()))


def subplan(plan, k):
    return dataclasses.replace(plan, poses=plan.poses[:k])


class FakeCell:
    """FakeRobot + emulated motor + simulated camera seeing the twin (no sockets)."""

    def __init__(self, world, hide_target=lambda: False):

        cell = load_cell("reference")
        self.robot = FakeRobot(cell.home, time_scale=25)
        self.emu = MotorEmulator(speed_deg_s=2000).start()
        self.motor = SerialPanMotor(self.emu.port, timeout=0.05, retries=2)
        self.hide_target = hide_target

        def scene():
            if self.hide_target():
                return []
            q = self.robot.arm.actual(self.robot.now())
            pan = math.radians(self.emu.position_deg())
            T = world.T_instr_target0(q, self.robot.arm.approach) @ T_target_plate(pan)
            return [(T, world.target)]

        cam = SimStereoCamera(
            scaled_rig(world.rig, 0.25), scene, static=[(world.T_instr_board, world.board)]
        )
        self.station = station_in_world(
            cell, world, self.robot, self.motor, cam, closers=[self.emu.stop, self.motor.close]
        )

    def close(self):
        self.station.close()


def test_settle_detection_waits_for_the_ringing_to_die():
    t = np.arange(0, 0.6, 0.008)
    ring = 1.5e-4 * np.exp(-t / 0.06) * np.sin(2 * np.pi * 8 * t)
    Q = np.outer(ring, np.ones(6))
    settled_at = next(k for k in range(len(t)) if is_settled(t[: k + 1], Q[: k + 1], 0.15, 2e-5))
    assert 0.25 < t[settled_at] < 0.45  # not before the ringing is below 20 µrad p-p
    assert not is_settled(t[:5], np.zeros((5, 6)), 0.15, 2e-5)  # too short a window


def test_complete_run_writes_csv_journal_images(world, plan, tmp_path):
    fc = FakeCell(world)
    events = []
    try:
        res = run_plan(
            fc.station, subplan(plan, 3), tmp_path / "r", settings=SETTINGS, progress=events.append
        )
    finally:
        fc.close()
    assert res.complete and res.n_measured == 3 and res.n_failed == 0
    st = read_journal(tmp_path / "r" / JOURNAL)
    assert st.ended and sorted(st.measured) == [1, 2, 3]
    for rec in st.captured.values():
        for img in rec.images:
            assert (tmp_path / "r" / img).stat().st_size > 10_000
    csv = (tmp_path / "r" / "measurements.csv").read_text().splitlines()
    header = next(ln for ln in csv if not ln.startswith("#"))
    assert header.startswith("pose_id,q1,") and ",pan," in header
    assert [ln.split(",")[0] for ln in csv if ln.startswith("P")] == ["P001", "P002", "P003"]
    kinds = [e.kind for e in events]
    assert kinds[0] == "preflight" and kinds[-1] == "done" and kinds.count("pose") == 3
    assert res.selfcheck_ok is True and res.selfcheck_drift_mm < 0.05
    # the measurement is the twin's truth within the vision accuracy (small images: ~0.1 mm)
    from quickhealth.station.formats import read_measurements

    m = read_measurements(tmp_path / "r" / "measurements.csv")
    T = world.twin.true_pose(m.q)
    err = np.linalg.norm(m.pos - T[:, :3, 3], axis=1)
    assert np.all(err < 5 * np.linalg.norm(m.sigma_pos, axis=1) + 2e-5)


def test_undetected_target_is_retried_then_recorded_as_failed(world, plan, tmp_path):
    hidden = {"on": False}
    fc = FakeCell(world, hide_target=lambda: hidden["on"])
    orig = fc.robot.move

    def move(q, *a, **k):  # hide the target at the second pose only
        hidden["on"] = np.allclose(q, plan.poses[1].q)
        return orig(q, *a, **k)

    fc.robot.move = move
    try:
        res = run_plan(fc.station, subplan(plan, 3), tmp_path / "r", settings=SETTINGS)
    finally:
        fc.close()
    assert res.complete and res.n_measured == 2 and res.n_failed == 1
    summary = json.loads((tmp_path / "r" / "run.json").read_text())
    assert summary["failed"][0]["name"] == "P002"
    assert "target not detected (0 markers" in summary["failed"][0]["reason"]
    assert "after 2 captures" in summary["failed"][0]["reason"]


def test_protective_stop_stops_cleanly_and_resume_loses_or_repeats_nothing(world, plan, tmp_path):
    fc = FakeCell(world)
    run_dir = tmp_path / "r"
    try:
        fc.robot.inject("protective_stop", after_moves=3)
        res = run_plan(fc.station, subplan(plan, 5), run_dir, settings=SETTINGS)
        assert res.stopped and "protective stop" in res.stopped and "--resume" in res.stopped
        st = read_journal(run_dir / JOURNAL)
        assert sorted(st.captured) == [1, 2] and sorted(st.measured) == [1, 2] and st.stops
        assert (run_dir / "measurements.csv").is_file()  # what was captured is kept
        fc.robot.release()
        res2 = run_plan(fc.station, subplan(plan, 5), run_dir, resume=True, settings=SETTINGS)
    finally:
        fc.close()
    assert res2.complete and res2.n_measured == 5
    from quickhealth.identify.errors import InputError

    with pytest.raises(InputError, match="already complete"):
        run_plan(fc.station, subplan(plan, 5), run_dir, resume=True, settings=SETTINGS)
    with pytest.raises(InputError, match="already holds a run"):
        run_plan(fc.station, subplan(plan, 5), run_dir, settings=SETTINGS)
    st = read_journal(run_dir / JOURNAL)
    assert st.resumes == 1 and sorted(st.captured) == [1, 2, 3, 4, 5]
    names = [ln.split(",")[0] for ln in (run_dir / "measurements.csv").read_text().splitlines()]
    assert [n for n in names if n.startswith("P")] == ["P001", "P002", "P003", "P004", "P005"]
    # the arm re-approached P002 before P003: the joint approach directions are unchanged
    moves = [m[0] for m in fc.robot.moves]
    i3 = max(i for i, q in enumerate(moves) if np.allclose(q, plan.poses[2].q))
    assert np.allclose(moves[i3 - 1], plan.poses[1].q)


def test_serial_garbage_is_survived_and_a_dead_motor_stops_the_run(world, plan, tmp_path):
    from quickhealth.identify.errors import HardwareError

    fc = FakeCell(world)
    try:
        fc.emu.inject("garbage", count=20)
        res = run_plan(fc.station, subplan(plan, 2), tmp_path / "a", settings=SETTINGS)
        assert res.complete and res.n_measured == 2
        fc.emu.clear()
        # Dead before the run: pre-flight refuses, nothing moves, no journal.
        fc.emu.inject("silent")
        n_moves = len(fc.robot.moves)
        with pytest.raises(HardwareError, match="pan motor .* does not answer"):
            run_plan(fc.station, subplan(plan, 2), tmp_path / "b", settings=SETTINGS)
        assert len(fc.robot.moves) == n_moves
        assert not (tmp_path / "b" / JOURNAL).exists()
        fc.emu.clear()

        # Dies mid-run: the run stops cleanly after the first pose, which is kept.
        def progress(p):
            if p.kind == "pose":
                fc.emu.inject("silent")

        res = run_plan(
            fc.station, subplan(plan, 3), tmp_path / "c", settings=SETTINGS, progress=progress
        )
    finally:
        fc.close()
    assert res.stopped and "pan motor" in res.stopped and "cable" in res.stopped
    st = read_journal(tmp_path / "c" / JOURNAL)
    assert sorted(st.captured) == [1] and st.stops and not st.ended


def test_cancel_stops_after_the_current_pose(world, plan, tmp_path):
    fc = FakeCell(world)
    cancel = threading.Event()

    def progress(p):
        if p.kind == "pose":
            cancel.set()

    try:
        res = run_plan(
            fc.station,
            subplan(plan, 3),
            tmp_path / "r",
            settings=SETTINGS,
            progress=progress,
            cancel=cancel,
        )
    finally:
        fc.close()
    assert res.stopped and "cancelled" in res.stopped
    assert sorted(read_journal(tmp_path / "r" / JOURNAL).captured) == [1]
