"""The line trigger end to end on the simulated cell: the real ur-rtde client pulses the
simulated controller's standard digital output through ``RTDEIOInterface`` (its io thread in
the client process), the controller's output terminal drives the cell's trigger cable, and the
cable's rising edge exposes both of pypylon's emulated cameras (their trigger source ``Line1``).

A run of a short plan measures every pose, each capture's journal record holding the edge as
the controller's stream confirmed it (and the cable saw it), sent with the arm at rest; with
the cable cut the capture times out in one line, nothing is measured, and the mended cable
lets ``resume`` finish the run; an edge that reaches one camera twice (a bouncing line) puts
the pair out of step: it is rejected, never measured, and taken again on the next pulse.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon lists its cameras

import numpy as np
import pytest

from quickhealth.station.hardware.cameras.config import Trigger
from quickhealth.station.hardware.robot import REST_TOL_RAD
from quickhealth.station.planning import load_cell, load_plan
from quickhealth.station.planning.planfile import content_hash, plan_to_dict
from quickhealth.station.planning.planner import plan_loop
from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal
from quickhealth.station.run.loop import run_plan
from quickhealth.station.run.settings import RunSettings
from quickhealth.station.sim.cell import sim_station

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

CAMERAS = """
[cameras]
backend = "pylon"
pixel_format = "Mono8"
trigger = "line"
robot_output = 2
pulse_ms = 20
exposure_us = 10000
timeout_ms = 250
attempts = 2
"""
SETTINGS = RunSettings(capture_attempts=2)


@pytest.fixture(scope="module")
def line_cell(tmp_path_factory):  # type: ignore[no-untyped-def]
    """A cell file with the line trigger, a 4-pose plan made for it, and the simulated cell
    (the real ur-rtde client, the controller simulator, pypylon's emulated cameras)."""
    d = tmp_path_factory.mktemp("line")
    src = Path(__file__).resolve().parents[2] / "station/data/reference_cell.toml"
    path = d / "line_cell.toml"
    path.write_text(src.read_text() + CAMERAS)
    cell = load_cell(str(path))
    assert cell.cameras is not None and cell.cameras.trigger is Trigger.LINE
    doc = plan_to_dict(plan_loop(cell, 8, seed=1))
    doc["poses"] = doc["poses"][:4]
    doc["hash"] = content_hash(doc)
    (d / "plan.json").write_text(json.dumps(doc))
    plan = load_plan(d / "plan.json")
    station, sim = sim_station(str(path), image_scale=0.25, speed_factor=20, cameras=cell.cameras)
    try:
        yield station, sim, plan
    finally:
        station.close()


def carried(edge: dict, edges: list[float]) -> int:
    """The index of the one edge the cable carried inside the journal's bracket of ``edge``
    (after ``rise_t - rise_window_ms``, at or before ``rise_t``: controller time)."""
    t1 = edge["rise_t"]
    t0 = t1 - edge["rise_window_ms"] / 1e3
    inside = [k for k, t in enumerate(edges) if t0 + 1e-6 < t <= t1 + 1e-6]
    assert len(inside) == 1, (edge, edges)
    return inside[0]


def test_each_pair_is_taken_on_one_edge_and_a_pair_out_of_step_is_rejected(
    line_cell, tmp_path
) -> None:  # type: ignore[no-untyped-def]
    """Every pose measured, each pair on one edge of the robot's output sent with the arm at
    rest.  After pose 2 the next edge reaches the left camera twice (contact bounce, ringing
    on the cable): the left camera exposes twice, the pair is out of step and rejected; the
    robot pulses again and pose 3 is measured once, from the clean pair."""
    station, sim, plan = line_cell
    stats = station.camera.device.stats  # type: ignore[attr-defined]
    n0, pairs0, oos0 = len(sim.cable.edges), stats["pairs"], stats["out_of_step"]

    def bounce_after_pose_2(ev):  # type: ignore[no-untyped-def]
        if ev.kind == "pose" and ev.index == 2:
            sim.cable.bounce("left")

    res = run_plan(station, plan, tmp_path / "run", settings=SETTINGS, progress=bounce_after_pose_2)
    assert res.complete and res.n_measured == 4, res.stopped
    st = read_journal(tmp_path / "run" / JOURNAL)
    assert sorted(st.measured) == [1, 2, 3, 4]
    edges = [e.t for e in sim.cable.edges[n0:]]
    # one rising edge at the controller's output for every pair the run took (pre-flight,
    # self-checks, poses), each carried by the cable, and one for the pair rejected
    assert len(edges) == stats["pairs"] - pairs0 + 1 >= 4 + 2 + 1
    assert stats["out_of_step"] == oos0 + 1
    rises = []
    for k, rec in sorted(st.captured.items()):
        cam = rec.camera
        assert cam["trigger"] == "line" and bool(cam.get("recaptured")) == (k == 3)
        e = cam["edge"]
        assert e["output"] == 2 and e["width_ms"] >= 20.0  # never shorter than asked
        cycles = np.array([e["rise_t"], e["rise_t"] + e["width_ms"] / 1e3]) / 0.008  # CB3
        assert np.allclose(cycles, np.round(cycles), atol=1e-3)  # each edge at a cycle
        assert e["rest_urad"] <= REST_TOL_RAD * 1e6  # fired with the arm at rest
        carried(e, edges)  # the edge the cable carried
        rises.append(e["rise_t"])
    assert rises == sorted(rises)
    again = st.captured[3].camera
    assert any("out of step" in p for p in again["recaptured"]), again
    # pose 3's pair is the second pulse after pose 2's: the first one's pair was rejected
    assert carried(again["edge"], edges) == carried(st.captured[2].camera["edge"], edges) + 2
    assert sim.controller.state()["digital_out"] & (1 << 2) == 0  # the output left low


def test_a_cut_cable_times_out_in_one_line_and_nothing_is_measured(line_cell, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The cable cut after pose 1: pose 2's capture times out in one line, pose 2 is neither
    captured nor measured (the robot pulsed: the edges never arrived); the cable mended,
    ``resume`` captures and measures pose 2 once."""
    station, sim, plan = line_cell
    plan = dataclasses.replace(plan, poses=plan.poses[:2])
    run_dir = tmp_path / "cut"

    def cut_after_pose_1(ev):  # type: ignore[no-untyped-def]
        if ev.kind == "pose" and ev.index == 1:
            sim.cable.cut()

    try:
        res = run_plan(station, plan, run_dir, settings=SETTINGS, progress=cut_after_pose_1)
        lost = len(sim.cable.edges) - sim.cable.carried
    finally:
        sim.cable.mend()
    assert res.stopped is not None and "\n" not in res.stopped
    assert "no good stereo pair in 2 attempts" in res.stopped
    assert "missing trigger edge" in res.stopped and "--resume" in res.stopped
    assert lost == 2  # the robot pulsed for both attempts: the edges never arrived
    st = read_journal(run_dir / JOURNAL)
    assert sorted(st.captured) == [1] and sorted(st.measured) == [1] and not st.failed
    res = run_plan(station, plan, run_dir, resume=True, settings=SETTINGS)  # cable mended
    assert res.complete and res.n_measured == 2
    caps = [r["index"] for _, r, _ in iter_records(run_dir / JOURNAL) if r["type"] == "captured"]
    assert sorted(caps) == [1, 2]  # nothing lost, nothing captured twice
    st = read_journal(run_dir / JOURNAL)
    assert all(r.camera["edge"]["output"] == 2 for r in st.captured.values())
