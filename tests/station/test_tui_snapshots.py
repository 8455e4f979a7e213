"""SVG snapshots of the main screens at 80×24 (SSH terminal) and 120×40.

Each snapshot is textual's own SVG export of the screen, compared byte for byte with the file
under ``tests/station/__snapshots__/test_tui_snapshots/``.  After a deliberate UI change,
look at the new SVG (written beside the test's tmp folder on failure) and re-approve with::

    QH_SNAPSHOT_UPDATE=1 .venv/bin/pytest tests/station/test_tui_snapshots.py

(pytest-textual-snapshot would pull syrupy, which pins pytest below 9; this is its core.)
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station.formats import write_measurements
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.facade import Facade

SNAPSHOTS = Path(__file__).parent / "__snapshots__" / "test_tui_snapshots"
SIZES = [(80, 24), (120, 40)]


def assert_snapshot(app: QuickhealthApp, name: str, tmp: Path) -> None:
    svg = app.export_screenshot(title=name)
    path = SNAPSHOTS / f"{name}.svg"
    if os.environ.get("QH_SNAPSHOT_UPDATE"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(svg, encoding="utf-8")
        return
    if not path.exists():
        pytest.fail(f"no snapshot {path.name}: approve it with QH_SNAPSHOT_UPDATE=1")
    if path.read_text(encoding="utf-8") != svg:
        new = tmp / f"{name}.svg"
        new.write_text(svg, encoding="utf-8")
        pytest.fail(f"{name} differs from {path}; new rendering in {new}")


@pytest.fixture(scope="module")
def data_station(tmp_path_factory: pytest.TempPathFactory) -> Facade:
    """A station on a twin data set (hidden backlash of joint 2), fitted once for all sizes."""
    tmp = tmp_path_factory.mktemp("snap")
    twin = make_twin(seed=21, effects={"backlash:j2": 4e-4})
    q = random_joints(twin.robot, 50, seed=22, T_instr_base=twin.truth.T_instr_base)
    run = tmp / "2026-11-01-nightly"
    run.mkdir()
    meta = {"run_id": "2026-11-01-nightly", "time_utc": "2026-11-01T02:00:00Z"}
    write_measurements(run / "measurements.csv", twin.measure(q[:30], seed=23, meta=meta))
    write_measurements(tmp / "heldout.csv", twin.measure(q[30:], seed=24))
    return Facade.from_data(
        run / "measurements.csv",
        tmp / "heldout.csv",
        archive_root=tmp / "archive",
        robot_name="ur5-cell3",
        max_order=3,
    )


async def visit(app: QuickhealthApp, pilot, key: str) -> None:  # type: ignore[no-untyped-def]
    await pilot.press(key)
    for _ in range(3):
        await pilot.pause()
        await app.workers.wait_for_complete()
    await pilot.pause()


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
async def test_main_screens(
    data_station: Facade, size: tuple[int, int], tmp_path: Path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    tag = f"{size[0]}x{size[1]}"
    # the screens show the archive relative to the working folder: the same on every machine
    monkeypatch.chdir(data_station.archive.root.parent)
    app = QuickhealthApp(data_station)
    async with app.run_test(size=size) as pilot:
        await visit(app, pilot, "1")
        assert "NO-GO" in str(app.screen.query_one("#verdict").render())
        assert_snapshot(app, f"station_{tag}", tmp_path)
        await visit(app, pilot, "3")
        assert app.screen.query_one("#poses").row_count == 30
        assert_snapshot(app, f"run_{tag}", tmp_path)
        await visit(app, pilot, "4")
        assert app.screen.health is not None
        assert_snapshot(app, f"results_{tag}", tmp_path)
        await visit(app, pilot, "5")
        assert app.screen.diagnosis is not None
        assert_snapshot(app, f"diagnose_{tag}", tmp_path)
        await visit(app, pilot, "6")
        assert app.screen.history is not None and len(app.screen.history.rows) == 1
        assert_snapshot(app, f"history_{tag}", tmp_path)
