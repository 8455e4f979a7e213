"""Fleet reprocessing: 20 archived runs on a Dask LocalCluster give what the local path gives."""

import pickle
import time
from pathlib import Path

import numpy as np
import pytest
import qh_runs as _runs

from quickhealth.station.archive import Archive
from quickhealth.station.cli import main
from quickhealth.station.reprocess import jobs_for_archive, reprocess, reprocess_run


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Two robots, 10 runs each (small runs: 25 poses, order-1 model)."""
    base = tmp_path_factory.mktemp("fleet")
    a = Archive.open(base / "arch")
    for k in range(20):
        d = _runs.make_run(
            base / f"src{k}", k, n_poses=25, time_utc=f"2026-01-{k + 1:02d}T08:00:00Z", light=True
        )
        a.add_run(f"ur5-{k % 2}", d, run_id=f"run{k:02d}")
    return a


def _same(a, b):
    assert [(r.robot, r.run_id, r.ok) for r in a] == [(r.robot, r.run_id, r.ok) for r in b]
    for x, y in zip(a, b, strict=True):
        assert x.ok, x.error
        np.testing.assert_allclose(x.coeffs, y.coeffs, rtol=0, atol=1e-12)
        for f in ("mean", "std", "max"):
            assert x.figures_mm[f] == pytest.approx(y.figures_mm[f], abs=1e-12)


@pytest.mark.slow
def test_localcluster_equals_local_path(fleet):
    from distributed import Client, LocalCluster

    jobs = jobs_for_archive(fleet, tag="t1", workspace_samples=1000)
    assert len(jobs) == 20
    t0 = time.perf_counter()
    local = reprocess(jobs, workers=2)
    t1 = time.perf_counter()
    # threads keep the test fast; the jobs and results must still pickle for remote workers
    assert pickle.loads(pickle.dumps(jobs)) == jobs
    assert pickle.loads(pickle.dumps(local)) == local
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cl:
        with Client(cl) as client:
            seen = []
            dask = reprocess(jobs, scheduler=client, progress=lambda k, n, r: seen.append(k))
        t2 = time.perf_counter()
        # the command line reaches the same cluster by its address
        rc = main(["reprocess", "ur5-0", "--archive", str(fleet.root), "--runs", "run00,run02",
                   "--tag", "addr", "--workspace-samples", "1000", "--scheduler", cl.scheduler_address])  # fmt: skip
        assert rc == 0
    from quickhealth.station import formats

    for r in local:
        if r.robot == "ur5-0" and r.run_id in ("run00", "run02"):  # written by the CLI run
            written = formats.read_model(Path(r.out_dir).parent / "addr" / "model.json").coeffs
            np.testing.assert_allclose(written, r.coeffs, rtol=0, atol=1e-12)
    print(f"local {t1 - t0:.1f} s, LocalCluster {t2 - t1:.1f} s for {len(jobs)} runs")
    _same(local, dask)
    assert sorted(seen) == list(range(1, 21))
    # and both equal a plain in-process loop, and the original fits (same data, same orders)
    serial = [reprocess_run(j) for j in jobs[:3]]
    _same(serial, local[:3])
    orig = fleet.run_state(fleet.runs("ur5-0")[0])
    np.testing.assert_allclose(local[0].coeffs, orig.coeffs, atol=1e-9)
    assert Path(local[0].out_dir, "model.json").is_file()


def test_reprocess_command_local_and_failures(fleet, capsys):
    rc = main(
        [
            "reprocess",
            "ur5-1",
            "--archive",
            str(fleet.root),
            "--runs",
            "run01,run03",
            "--workers",
            "1",
            "--tag",
            "cli",
            "--workspace-samples",
            "500",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0 and out.count("ur5-1/run0") == 2
    assert (
        fleet.folder(fleet.get("ur5-1", "run03")) / "reprocessed" / "cli" / "report.json"
    ).is_file()
    # a calibration but no stored images to re-detect: the job fails, the command says so
    cal = fleet.root / "cal.json"
    cal.write_text("{}")
    rc = main(
        [
            "reprocess",
            "ur5-1",
            "--archive",
            str(fleet.root),
            "--runs",
            "run01",
            "--workers",
            "1",
            "--calibration",
            str(cal),
        ]
    )
    assert rc == 3
    assert "FAILED" in capsys.readouterr().out


@pytest.fixture(scope="module")
def imaged_run(tmp_path_factory):
    """A 3-pose run of the simulated cell with its stored stereo images (small sensor)."""
    import dataclasses
    import math

    import qh_station_plan as station_plan

    from quickhealth.station.hardware.cameras import SimStereoCamera, scaled_rig
    from quickhealth.station.hardware.motor import SerialPanMotor
    from quickhealth.station.hardware.motor_emulator import MotorEmulator
    from quickhealth.station.hardware.target import T_target_plate
    from quickhealth.station.hardware.world import build_world
    from quickhealth.station.planning import load_cell, load_plan
    from quickhealth.station.run import RunSettings, Station, run_plan
    from quickhealth.station.sim.fake_robot import FakeRobot
    from quickhealth.station.vision_io import rig_to_json, write_json

    base = tmp_path_factory.getbasetemp()
    plan = load_plan(station_plan.plan_file(base))
    plan = dataclasses.replace(plan, poses=plan.poses[:3])
    world = build_world("reference", twin_seed=1)
    cell = load_cell("reference")
    robot = FakeRobot(cell.home, time_scale=25)
    emu = MotorEmulator(speed_deg_s=2000).start()
    motor = SerialPanMotor(emu.port, timeout=0.05, retries=2)
    rig = scaled_rig(world.rig, 0.25)

    def scene():
        q = robot.arm.actual(robot.now())
        T = world.T_instr_target0(q, robot.arm.approach) @ T_target_plate(
            math.radians(emu.position_deg())
        )
        return [(T, world.target)]

    camera = SimStereoCamera(rig, scene, static=[(world.T_instr_board, world.board)])
    station = Station.on_simulated_world(
        cell, world, robot, motor, camera, closers=[emu.stop, motor.close]
    )
    run_dir = base / "imaged"
    try:
        run_plan(station, plan, run_dir, settings=RunSettings(capture_attempts=2))
    finally:
        station.close()
    cal = base / "cal_same.json"
    write_json(cal, rig_to_json(rig))
    T = rig.T_left_right.copy()
    T[:3, 3] *= 1.01  # a calibration with a 1 % longer baseline
    longer = dataclasses.replace(rig, T_left_right=T)
    cal2 = base / "cal_longer.json"
    write_json(cal2, rig_to_json(longer))
    return run_dir, cal, cal2, world


@pytest.mark.slow
def test_redetect_with_a_new_calibration(imaged_run):
    from quickhealth.station import formats
    from quickhealth.station.reprocess import redetect_run

    run_dir, cal, cal2, world = imaged_run
    old = formats.read_measurements(run_dir / "measurements.csv")
    same = redetect_run(run_dir, cal, target=world.target)
    assert same.pose_id == old.pose_id
    np.testing.assert_allclose(same.pos, old.pos, atol=1e-6)  # same images, same rig
    np.testing.assert_allclose(same.q, old.q, atol=1e-9)
    new = redetect_run(run_dir, cal2, target=world.target)
    depth_old = np.linalg.norm(old.pos, axis=1)
    depth_new = np.linalg.norm(new.pos, axis=1)
    # a longer baseline puts the target farther away, by about the same 1 %
    np.testing.assert_allclose(depth_new / depth_old, 1.01, atol=2e-3)
