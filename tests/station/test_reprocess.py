"""Fleet reprocessing: 20 archived runs on a real Dask cluster (`dask scheduler` and two
`dask worker` processes on loopback) give what the local path gives, survive a killed
worker, and an unreachable scheduler is one line and exit 3."""

import json
import pickle
import time
from pathlib import Path

import numpy as np
import pytest
import qh_runs as _runs

from quickhealth.station.archive import Archive, run_state
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


@pytest.fixture(scope="module")
def cluster():
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1, stopped afterwards."""
    import qh_dask

    try:
        cl = qh_dask.DaskCluster(n_workers=2).start()
    except RuntimeError as exc:
        pytest.fail(str(exc), pytrace=False)
    yield cl
    cl.stop()


def _written(results, tag):
    from quickhealth.station import formats

    out = {}
    for r in results:
        d = Path(r.out_dir).parent / tag
        rep = formats.read_report(d / "report.json")
        out[(r.robot, r.run_id)] = (formats.read_model(d / "model.json").coeffs, rep["workspace"])
    return out


@pytest.mark.slow
def test_dask_cluster_equals_local_path(fleet, cluster, capsys):
    """The command line on a real cluster writes what the local processes compute."""
    jobs = jobs_for_archive(fleet, tag="local", workspace_samples=1000)
    assert len(jobs) == 20
    t0 = time.perf_counter()
    local = reprocess(jobs, workers=2)
    t1 = time.perf_counter()
    assert pickle.loads(pickle.dumps(jobs)) == jobs
    rc = main(["reprocess", "--archive", str(fleet.root), "--tag", "dask",
               "--workspace-samples", "1000", "--scheduler", cluster.address])  # fmt: skip
    t2 = time.perf_counter()
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    print(f"local {t1 - t0:.1f} s, Dask cluster {t2 - t1:.1f} s for {len(jobs)} runs")
    # progress: one line per finished run, counting up to 20, with the time left
    prog = [line for line in cap.err.splitlines() if line.strip().startswith("[")]
    assert len(prog) == 20 and prog[-1].strip().startswith("[20/20]") and "left)" in prog[-1]
    assert f"on Dask scheduler {cluster.address}" in cap.err
    on_dask = _written(local, "dask")
    for r in local:
        assert r.ok, r.error
        coeffs, ws = on_dask[(r.robot, r.run_id)]
        np.testing.assert_allclose(coeffs, r.coeffs, rtol=0, atol=1e-12)
        for f in ("mean", "std", "max"):
            assert ws[f"{f}_mm"] == pytest.approx(r.figures_mm[f], abs=1e-12)
    # and the local path equals a plain in-process loop and the original fit
    _same([reprocess_run(j) for j in jobs[:2]], local[:2])
    orig = run_state(fleet, fleet.runs("ur5-0")[0])
    np.testing.assert_allclose(local[0].coeffs, orig.coeffs, atol=1e-9)


@pytest.mark.slow
def test_dask_survives_a_worker_killed_mid_job(fleet, cluster, capsys):
    """SIGKILL a worker while it runs a job: the scheduler runs the job again on the other
    worker; every run is reprocessed once, the index keeps one row per run."""
    import threading

    from distributed import Client

    n_rows = sum(len(fleet.runs(r)) for r in fleet.robots())
    out: dict[str, int] = {}
    argv = ["reprocess", "--archive", str(fleet.root), "--tag", "killed",
            "--workspace-samples", "4000", "--scheduler", cluster.address, "--update-index"]  # fmt: skip
    th = threading.Thread(target=lambda: out.setdefault("rc", main(argv)))
    killed = None
    with Client(cluster.address, timeout="20s") as c:
        th.start()
        t_end = time.monotonic() + 120
        while killed is None and time.monotonic() < t_end and th.is_alive():
            busy = {
                w: ks for w, ks in c.processing().items() if ks and "w1" in c.scheduler_info()["workers"].get(w, {}).get("name", "")
            }  # fmt: skip
            if busy:
                time.sleep(0.05)  # into the job
                cluster.kill_worker("w1")
                killed = busy
            time.sleep(0.01)
        th.join(timeout=240)
    cap = capsys.readouterr()
    try:
        assert killed, "worker w1 never got a job"
        assert not th.is_alive() and out["rc"] == 0, cap.err
        lines = [x for x in cap.out.splitlines() if "poses, rms" in x]
        assert len(lines) == 20 and len(set(lines)) == 20  # every run once
        assert sum(len(fleet.runs(r)) for r in fleet.robots()) == n_rows  # no row doubled
        local = {(r.robot, r.run_id): r for r in reprocess(jobs_for_archive(fleet, tag="kref", workspace_samples=4000), workers=2)}  # fmt: skip
        for rb in fleet.robots():
            for rec in fleet.runs(rb):
                folder = fleet.folder(rec) / "reprocessed"
                assert (folder / "killed" / "model.json").is_file()
                assert rec.max_mm == pytest.approx(
                    local[(rb, rec.run_id)].figures_mm["max"], abs=1e-12
                )
        print(f"killed w1 while it ran {list(killed.values())[0]}; 20 of 20 runs done once")
    finally:
        cluster.start_worker("w1")  # the cluster as it was, for the next test
        cluster.wait_for_workers(2, 90)


def test_unreachable_scheduler_is_one_line_and_exit_3(fleet, capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there once closed
    rc = main(["reprocess", "--archive", str(fleet.root), "--runs", "run00", "ur5-0",
               "--scheduler", f"tcp://127.0.0.1:{port}", "--scheduler-timeout", "2"])  # fmt: skip
    err = capsys.readouterr().err
    # what it was about to do (the banner), then exactly one line saying what went wrong
    lines = [x for x in err.splitlines() if not x.startswith("reprocessing ")]
    assert rc == 3
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("quickhealth: error: "), err
    assert f"cannot reach the Dask scheduler tcp://127.0.0.1:{port}" in lines[0]


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

    from quickhealth.station.formats.vision import rig_to_json, write_json
    from quickhealth.station.hardware.motor import SerialPanMotor
    from quickhealth.station.hardware.target import T_target_plate
    from quickhealth.station.planning import load_cell, load_plan
    from quickhealth.station.run.loop import run_plan
    from quickhealth.station.run.settings import RunSettings
    from quickhealth.station.sim.cameras import SimStereoCamera, scaled_rig
    from quickhealth.station.sim.cell import station_in_world
    from quickhealth.station.sim.fake_robot import FakeRobot
    from quickhealth.station.sim.motor_emulator import MotorEmulator
    from quickhealth.station.sim.world import build_world

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
    station = station_in_world(cell, world, robot, motor, camera, closers=[emu.stop, motor.close])
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


# ---- issue 32: the fleet network: sockets where the user says, jobs without credentials


@pytest.mark.slow
def test_documented_cluster_listens_only_where_the_user_said(cluster):
    """docs/monitoring.md's one-machine commands (the fixture's, with free ports): every
    listening socket of the scheduler and the workers, dashboards included, is on 127.0.0.1.
    With Dask's defaults the dashboard and the workers listened on 0.0.0.0 and [::]."""
    socks = cluster.listening()
    kinds = {name for _, _, name in socks}
    assert {"scheduler", "w0", "w1"} <= kinds, socks
    assert sum(name == "scheduler" for _, _, name in socks) >= 2, socks  # comm + dashboard
    assert all(ip == "127.0.0.1" for ip, _, _ in socks), socks


def test_a_plain_tcp_cluster_off_this_machine_is_refused(fleet, capsys, tmp_path):
    argv = ["reprocess", "--archive", str(fleet.root), "--runs", "run00", "ur5-0"]
    assert main([*argv, "--scheduler", "tcp://192.0.2.10:8786"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a plain tcp:// cluster off this machine is open" in err
    assert main([*argv, "--scheduler", "tls://192.0.2.10:8786", "--tls-cert", "x.pem"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs --tls-ca-file, --tls-key" in err
    from quickhealth.station.reprocess import scheduler_security

    for n in ("ca.pem", "c.pem", "c.key"):
        (tmp_path / n).write_text("-")
    sec = scheduler_security("tls://10.0.0.5:8786", *(str(tmp_path / n) for n in ("ca.pem", "c.pem", "c.key")))  # fmt: skip
    assert sec.require_encryption and sec.tls_client_cert == str(tmp_path / "c.pem")


@pytest.mark.slow
def test_index_password_never_written_nor_sent_to_workers(pg_server, tmp_path, cluster, capsys):
    """`reprocess --report --db URL-with-password`: no file the product writes holds the
    password, the jobs (what a Dask worker receives) do not carry it, and a worker finds the
    index in its own environment (QUICKHEALTH_DB_FILE) or fails the job with one line."""
    secret = "S3cret-pw"
    url = pg_server.new_database().replace("://qh@", f"://qh:{secret}@")  # trust: accepted
    arch = Archive.open(tmp_path / "arch", url)
    for k in range(2):
        d = _runs.make_run(tmp_path / f"src{k}", k, n_poses=25, time_utc=f"2026-01-0{k + 1}T08:00:00Z", light=True)  # fmt: skip
        arch.add_run("ur5-pw", d, run_id=f"run{k}")
    argv = ["reprocess", "ur5-pw", "--archive", str(arch.root), "--db", url, "--report",
            "--runs", "run1", "--workspace-samples", "500"]  # fmt: skip
    assert main([*argv, "--workers", "1", "--tag", "local"]) == 0, capsys.readouterr().err
    jobs = jobs_for_archive(arch, "ur5-pw", report=True)
    assert secret.encode() not in pickle.dumps(jobs)
    assert jobs[0].archive_index == url.replace(secret, "***")
    # a Dask worker without the index URL: the job fails, saying what to set, at once
    assert main([*argv, "--scheduler", cluster.address, "--tag", "dask"]) == 3
    out = capsys.readouterr().out
    assert "FAILED: QUICKHEALTH_DB_FILE=" in out and "cannot read the index URL" in out, out
    cluster.index_url_file.write_text(url + "\n")
    cluster.index_url_file.chmod(0o644)
    assert main([*argv, "--scheduler", cluster.address, "--tag", "dask"]) == 3
    assert "others may read it (mode 0644)" in capsys.readouterr().out
    cluster.index_url_file.chmod(0o600)
    try:
        assert main([*argv, "--scheduler", cluster.address, "--tag", "dask"]) == 0
    finally:
        cluster.index_url_file.unlink()
    assert "HEALTHY" in capsys.readouterr().out.upper()
    written = [p for p in arch.root.rglob("*") if p.is_file()]
    assert any(p.name == "reprocess.json" for p in written)
    leaks = [p for p in written if secret.encode() in p.read_bytes()]
    assert not leaks, leaks
    done = json.loads(next(p for p in written if p.name == "reprocess.json").read_text())
    assert done["job"]["archive_index"].startswith("postgresql+psycopg://qh:***@")


def test_reprocess_keeps_the_fits_row_limit(fleet, capsys, monkeypatch):
    """issue 32: reprocess refitted an archived run of 200 004 rows (48 s, 4.1 GB) that
    `identify fit` refuses; now every fitting door has the one limit.  (The limit lowered
    to 20 rows here, the runs have 25: the same check, without a 20 MB file.)"""
    from quickhealth.station.formats import measurements

    monkeypatch.setattr(measurements, "MAX_FIT_ROWS", 20)
    rc = main(["reprocess", "ur5-0", "--archive", str(fleet.root), "--runs", "run00",
               "--workers", "1", "--tag", "rows"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 3
    failed = [x for x in out.splitlines() if "FAILED" in x]
    assert len(failed) == 1 and "25 rows is over the fit's limit of 20" in failed[0], out
    assert not (fleet.folder(fleet.get("ur5-0", "run00")) / "reprocessed" / "rows").exists()
