"""Two stations, two indexes, one archive folder (issue 27): neither loses its run.

Station A keeps its index in the archive folder (the default SQLite file); station B shares
the folder but has its own index (another SQLite file, or a PostgreSQL database).  Both add a
run called ``run2`` of robot ``r`` at the same moment, several times over.  Before issue 27
the rule "a folder without a row is replaced" let B's add destroy A's run (A's index then
described B's files).  Now: exactly one wins the folder; the other is refused with one line
naming the folder and leaves it alone; each index's row describes the files in the folder it
points to; the refused station archives its run under another id; nothing is left in staging.
"""

from __future__ import annotations

import filecmp
import json
import multiprocessing as mp
from pathlib import Path

import pytest
import qh_runs

from quickhealth.identify.errors import InputError
from quickhealth.station.archive import MARKER, Archive, marker_owner


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    base = tmp_path_factory.mktemp("shared-src")
    a = qh_runs.make_run(base / "a" / "run2", 1, n_poses=25, light=True)
    b = qh_runs.make_run(base / "b" / "run2", 2, n_poses=25, light=True,
                         degrade={"j2.ex.c0": 3e-4})  # fmt: skip
    for d, tag in ((a, b"A"), (b, b"B")):
        (d / "images").mkdir()
        for j in range(3):  # a copy that takes a moment, as a real run's images do
            (d / "images" / f"{j:04d}_L.png").write_bytes(tag * 300_000)
    return a, b


def _station(root: str, url: str | None, src: str, result: str, barrier) -> None:  # child
    arch = Archive.open(root, url)
    barrier.wait()
    try:
        arch.add_run("r", src, run_id="run2", time_utc="2026-01-02T00:00:00Z")
        out = {"ok": True}
    except InputError as exc:
        out = {"ok": False, "error": str(exc)}
    Path(result).write_text(json.dumps(out))


def _same_tree(a: Path, b: Path) -> bool:
    cmp = filecmp.dircmp(a, b, ignore=[MARKER])
    if cmp.left_only or cmp.right_only or cmp.funny_files:
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    return not mismatch and not errors and all(_same_tree(a / d, b / d) for d in cmp.common_dirs)


@pytest.mark.parametrize("b_index", ["sqlite", "postgresql"])
def test_two_indexes_sharing_a_folder_never_lose_a_run(tmp_path, sources, b_index, request):
    ctx = mp.get_context("fork")
    wins = {"A": 0, "B": 0}
    for trial in range(4):
        root = tmp_path / f"shared{trial}"
        if b_index == "sqlite":
            url_b = f"sqlite:///{tmp_path / f'b{trial}.sqlite'}"
        else:
            url_b = request.getfixturevalue("pg_server").new_database()
        arch = {"A": Archive.open(root), "B": Archive.open(root, url_b)}
        assert arch["A"].index_id != arch["B"].index_id
        barrier = ctx.Barrier(2)
        res = {k: tmp_path / f"r{trial}{k}.json" for k in "AB"}
        procs = [
            ctx.Process(target=_station, args=(str(root), None, str(sources[0]), str(res["A"]),
                                               barrier)),
            ctx.Process(target=_station, args=(str(root), url_b, str(sources[1]), str(res["B"]),
                                               barrier)),
        ]  # fmt: skip
        for p in procs:
            p.start()
        for p in procs:
            p.join(120)
            assert p.exitcode == 0
        got = {k: json.loads(res[k].read_text()) for k in "AB"}
        winners = [k for k in "AB" if got[k]["ok"]]
        assert len(winners) == 1, got
        win, lose = winners[0], "B" if winners[0] == "A" else "A"
        wins[win] += 1
        src = dict(zip("AB", sources, strict=True))
        folder = root / "robots" / "r" / "run2"
        # the winner's index describes the files in the folder, and the folder is its own
        assert _same_tree(src[win], folder)
        assert marker_owner(folder) == arch[win].index_id
        rec = arch[win].get("r", "run2")
        assert rec.max_mm == pytest.approx(
            json.loads((src[win] / "report.json").read_text())["workspace"]["max_mm"]
        )
        # the loser was refused with one line naming the folder, and has no row for it
        assert "run2: holds a run put there by another index" in got[lose]["error"]
        assert "\n" not in got[lose]["error"]
        with pytest.raises(InputError, match="has no runs"):
            arch[lose].runs("r")
        # ... and archives its run under another id: nobody lost anything
        arch[lose].add_run("r", src[lose], run_id="run2-b")
        assert _same_tree(src[lose], root / "robots" / "r" / "run2-b")
        assert _same_tree(src[win], folder)
        assert not list((root / "robots" / "r").glob(".incoming-*"))
        for a in arch.values():
            a.engine.dispose()
    print(f"\nwins over 4 trials: {wins}")
