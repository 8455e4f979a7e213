"""Every worker a command starts ends with it (issue 27): SIGTERM, SIGINT, SIGHUP, SIGKILL.

Each parallel command (``identify fit --plots``, ``vision measure --jobs 2``, ``reprocess
--workers 2``) runs as the installed ``quickhealth`` script.  Once its worker processes are
there, the command (only its own process, as ``kill PID`` does) gets the signal.  Afterwards:
the command's exit status and one line, none of the processes it started still running
(descendants found through /proc while it ran: a worker left behind is re-parented to init,
where its parent's pid no longer finds it), and nothing half-written left.  Before issue 27
SIGTERM left the workers of ``fit --plots`` and ``vision measure`` running.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import qh_runs

from quickhealth.identify.transforms import make_T, rot_y
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats
from quickhealth.station.archive import Archive
from quickhealth.station.formats.vision import rig_to_json
from quickhealth.vision.boards import reference_target
from quickhealth.vision.camera import StereoRig
from quickhealth.vision.reference import T_left_rig, reference_rig
from quickhealth.vision.render import render_stereo

EXE = Path(sys.executable).with_name("quickhealth")

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc"),
]


def _stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, state) of a process, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return int(fields[1]), fields[0]


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` now (children, their children …)."""
    parent = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            st = _stat(int(d))
            if st is not None:
                parent[int(d)] = st[0]
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out.update(kids)
        todo += kids
    return out


def running(pids: set[int]) -> set[int]:
    """Those of ``pids`` still running (a zombie has ended)."""
    return {p for p in pids if (st := _stat(p)) is not None and st[1] != "Z"}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("workers")
    twin = make_twin(seed=3)  # a fit long enough to be interrupted: 400 poses, orders up to 6
    q = random_joints(twin.robot, 400, seed=4, T_instr_base=twin.truth.T_instr_base)
    formats.write_measurements(d / "meas.csv", twin.measure(q, seed=5))
    # a run folder of 80 stereo pairs (one rendered pair, hard-linked under 80 pose ids)
    r = reference_rig()
    rig = StereoRig(r.left.scaled(0.3), r.right.scaled(0.3), r.T_left_right)
    run = d / "vrun"
    (run / "images").mkdir(parents=True)
    (run / "calibration.json").write_text(json.dumps(rig_to_json(rig)))
    T = T_left_rig() @ make_T(rot_y(0.2), [0.05, 0.0, 1.8])
    left, right = render_stereo(rig, T, reference_target(), rng=np.random.default_rng(1))
    cv2.imwrite(str(run / "images" / "p0_left.png"), left)
    cv2.imwrite(str(run / "images" / "p0_right.png"), right)
    rows = ["pose_id,q1,q2,q3,q4,q5,q6,pan,time"]
    for k in range(80):
        for s in ("left", "right"):
            if k:
                os.link(run / "images" / f"p0_{s}.png", run / "images" / f"p{k}_{s}.png")
        rows.append(f"p{k},{0.1 * k},-90,90,0,45,0,0,{k}")
    (run / "images" / "index.csv").write_text("\n".join(rows) + "\n")
    # an archive of 12 runs to reprocess with a fresh order search each
    src = qh_runs.make_run(d / "src", 1, n_poses=25, light=True)
    arch = Archive.open(d / "arch")
    for k in range(12):
        arch.add_run("r", src, run_id=f"run{k:02d}")
    return d


def _sigint_default() -> None:
    """In the command's process before it starts: Ctrl-C's default.  A test run started in
    the background of a non-interactive shell (``make test &``) ignores SIGINT, its children
    inherit that, and Python then installs no KeyboardInterrupt handler: the command would
    rightly ignore the signal the test sends."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _argv(name: str, d: Path, out: Path) -> list[str]:
    if name == "fit-plots":
        return ["identify", "fit", str(d / "meas.csv"), "--robot", "ur5", "--out", str(out),
                "--plots", "--quiet"]  # fmt: skip
    if name == "vision-measure":
        return ["vision", "measure", str(d / "vrun"), "--jobs", "2", "--out", str(out)]
    return ["reprocess", "--archive", str(d / "arch"), "--workers", "2", "--orders", "select",
            "--tag", out.name]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "sig"),
    [
        ("fit-plots", signal.SIGTERM),
        ("fit-plots", signal.SIGHUP),
        ("fit-plots", signal.SIGKILL),  # no cleanup at all: the kernel ends the workers
        ("vision-measure", signal.SIGINT),
        ("reprocess", signal.SIGTERM),
    ],
    ids=lambda x: x.name if isinstance(x, signal.Signals) else x,
)
def test_a_stopped_command_leaves_no_worker_running(inputs, tmp_path, name, sig):
    if not EXE.exists():
        pytest.skip(f"{EXE} not installed")
    out = tmp_path / f"out-{sig.name}"
    err_file = tmp_path / "stderr.txt"
    with err_file.open("w") as err:  # not a pipe: a left worker would hold it open
        proc = subprocess.Popen([str(EXE), *_argv(name, inputs, out)], stdout=subprocess.DEVNULL,
                                stderr=err, cwd=tmp_path, preexec_fn=_sigint_default)  # fmt: skip
    seen: set[int] = set()
    try:
        t_end = time.monotonic() + 90
        while time.monotonic() < t_end and proc.poll() is None:
            seen |= descendants(proc.pid)
            if len(running(seen)) >= 2:  # the pool is up
                break
            time.sleep(0.02)
        assert proc.poll() is None, f"{name} ended before its workers were seen"
        assert len(running(seen)) >= 2, f"{name}: no workers seen"
        time.sleep(0.2)
        seen |= descendants(proc.pid)
        proc.send_signal(sig)
        rc = proc.wait(timeout=60)
        t_end = time.monotonic() + 10
        while running(seen) and time.monotonic() < t_end:
            time.sleep(0.05)
        left = running(seen)
        assert not left, f"{name} after {sig.name}: processes {sorted(left)} still running"
    finally:
        for p in running(seen) | ({proc.pid} if proc.poll() is None else set()):
            os.kill(p, signal.SIGKILL)  # only what this test started
        proc.wait(timeout=10)
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
        return
    lines = err_file.read_text().replace("\r", "\n").splitlines()
    errors = [x for x in lines if x.startswith("quickhealth")]
    want = "interrupted" if sig == signal.SIGINT else f"stopped by {sig.name}"
    assert rc == 3 and errors == [f"quickhealth: {want}"], (rc, lines[-5:])
    # nothing half-written: no output, no temporary folder or file
    assert not out.exists(), f"{out} was written"
    assert not list(tmp_path.glob(".identify-*")) and not list(tmp_path.glob(".*.tmp"))
    assert not list((inputs / "arch").rglob(".reprocess-*"))
