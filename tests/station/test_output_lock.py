"""One writer per --out at a time (issue 27): the lock is held for the whole command.

Before issue 27 two ``identify fit`` runs into one new ``--out`` both succeeded (8 of 8
trials), the second silently replacing the first's files: each checked the still empty
folder, then wrote.  Now the second is refused with one line (exit 3 while the first writes,
exit 2 once the folder holds the first's fit of other data) and the folder holds one fit.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
from pathlib import Path

import pytest

from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station import formats
from quickhealth.station.run.lock import OutputBusy, OutputLock


def test_second_writer_is_refused_naming_the_holder(tmp_path, monkeypatch):
    monkeypatch.setenv("QUICKHEALTH_LOCK_DIR", str(tmp_path / "locks"))
    out = tmp_path / "out"
    with OutputLock.acquire(out, "identify fit") as held:
        assert held.path.is_file()
        with OutputLock.acquire(out, "run"):  # re-entrant in one process (run --archive fits)
            pass
        assert held.path.is_file()
        # another process: refused at once, naming the holder
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child
            try:
                OutputLock.acquire(out, "plan")
                os.write(w, b"acquired")
            except OutputBusy as exc:
                os.write(w, str(exc).encode())
            os._exit(0)
        os.waitpid(pid, 0)
        said = os.read(r, 4096).decode()
        assert f"pid {os.getpid()}, identify fit, since" in said, said
        assert "another quickhealth command is writing there" in said
    assert not list((tmp_path / "locks").iterdir())  # nothing left behind
    with OutputLock.acquire(out, "again"):  # free again
        pass


def _fit_child(meas: str, out: str, result: str, barrier) -> None:  # pragma: no cover - child
    import contextlib
    import io

    from quickhealth.station.cli import main

    err = io.StringIO()
    barrier.wait()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["identify", "fit", meas, "--robot", "ur5", "--out", out, "--max-order", "1",
                   "--quiet"])  # fmt: skip
    Path(result).write_text(json.dumps({"rc": rc, "err": err.getvalue()}))


@pytest.mark.slow
def test_two_fits_into_one_new_out_at_once_one_wins(tmp_path, monkeypatch):
    monkeypatch.setenv("QUICKHEALTH_LOCK_DIR", str(tmp_path / "locks"))
    twin = make_twin(seed=5)
    data = []
    for k in range(2):
        q = random_joints(twin.robot, 40, seed=10 + k, T_instr_base=twin.truth.T_instr_base)
        p = tmp_path / f"meas{k}.csv"
        formats.write_measurements(p, twin.measure(q, seed=20 + k))
        data.append(p)
    ctx = mp.get_context("fork")
    for trial in range(3):
        out = tmp_path / f"out{trial}"
        barrier = ctx.Barrier(2)
        res = [tmp_path / f"res{trial}-{k}.json" for k in range(2)]
        procs = [
            ctx.Process(target=_fit_child, args=(str(data[k]), str(out), str(res[k]), barrier))
            for k in range(2)
        ]
        for p in procs:
            p.start()
        for p in procs:
            p.join(120)
            assert p.exitcode == 0
        got = [json.loads(r.read_text()) for r in res]
        ok = [k for k in range(2) if got[k]["rc"] == 0]
        assert len(ok) == 1, got  # never both
        loser = got[1 - ok[0]]
        lines = loser["err"].strip().splitlines()
        assert loser["rc"] in (2, 3) and len(lines) == 1, loser
        assert "another quickhealth command is writing there" in lines[0] or (
            "holds the fit of another measurement file" in lines[0]
        ), lines
        doc = json.loads((out / "report.json").read_text())
        assert Path(doc["input"]).name == data[ok[0]].name  # the winner's fit, whole
        assert not list(tmp_path.glob(".identify-*"))
    assert not list((tmp_path / "locks").iterdir())


# ---- issue 32: nothing is written through a link planted in a shared or run folder


def test_simulator_port_lock_never_follows_a_planted_link(tmp_path, monkeypatch):
    """The simulator's port lock lives in /tmp, shared by every user (the ports are): a link
    or a pipe planted under its name is refused in one line, never followed or blocked on."""
    from quickhealth.identify.errors import HardwareError
    from quickhealth.station.sim import process

    monkeypatch.setattr(process, "PORT_LOCK", str(tmp_path / "ports-{host}.lock"))
    victim = tmp_path / "victim"
    victim.write_text("mine")
    (tmp_path / "ports-127.0.0.9.lock").symlink_to(victim)
    with pytest.raises(HardwareError, match=r"ports-127\.0\.0\.9\.lock: a symbolic link stands"):
        process._port_lock("127.0.0.9")
    os.mkfifo(tmp_path / "ports-127.0.0.8.lock")  # an open for reading would block forever
    with pytest.raises(HardwareError, match=r"the port lock is not a plain file"):
        process._port_lock("127.0.0.8")
    assert victim.read_text() == "mine" and victim.stat().st_mode & 0o777 != 0o666
    fd = process._port_lock("127.0.0.7")  # made new, O_EXCL
    os.close(fd)
    assert (tmp_path / "ports-127.0.0.7.lock").is_file()


def test_journal_and_run_log_never_append_through_a_link(tmp_path):
    from quickhealth.identify.errors import InputError
    from quickhealth.station.fsio import open_append
    from quickhealth.station.run.journal import Journal

    victim = tmp_path / "victim"
    victim.write_text("mine")
    run = tmp_path / "run"
    run.mkdir()
    (run / "journal.jsonl").symlink_to(victim)
    (run / "run.log").symlink_to(victim)
    with pytest.raises(InputError, match=r"journal\.jsonl: cannot write: a symbolic link"):
        Journal(run).open()
    with pytest.raises(InputError, match=r"run\.log: cannot write: a symbolic link"):
        open_append(run / "run.log")
    assert victim.read_text() == "mine"


def test_lock_folder_checks(tmp_path, monkeypatch):
    """Made private when missing; a link or another user's folder is refused (one line)."""
    from quickhealth.station.run.lock import LockPlaceUnsafe, RunLock

    d = tmp_path / "new" / "locks"
    with RunLock.acquire(tmp_path / "r", directory=d):
        assert (d.stat().st_mode & 0o777) == 0o700
    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    (tmp_path / "link").symlink_to(real)
    with pytest.raises(LockPlaceUnsafe, match=r"link: the lock folder is a symbolic link"):
        RunLock.acquire(tmp_path / "r", directory=tmp_path / "link")
    os.chmod(real, 0o755)
    with pytest.raises(LockPlaceUnsafe, match=r"has mode 0755: others may use it"):
        OutputLock.acquire(tmp_path / "out", "plan", directory=real)
    assert not list(real.iterdir())
