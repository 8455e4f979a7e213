"""TUI on a measured data set: results, the diagnose loop on a hidden effect, history, UI liveness.

The data come from the digital twin with a hidden backlash on joint 2 (training and held-out
files in CSV v1); the App is driven with textual's pilot, through the real facade, fit,
diagnosis and archive.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from qh_tui import settle, text
from textual.worker import WorkerState

from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station.formats import write_measurements
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.facade import Facade


def hidden_effect_files(tmp: Path, n_train: int = 60, n_held: int = 60) -> tuple[Path, Path]:
    """Twin UR5 with a hidden backlash on joint 2 (~4× the noise floor), train + held-out CSVs."""
    twin = make_twin(seed=11, effects={"backlash:j2": 4e-4})
    q = random_joints(twin.robot, n_train + n_held, seed=12, T_instr_base=twin.truth.T_instr_base)
    run = tmp / "run-hidden"
    run.mkdir()
    train, held = run / "measurements.csv", tmp / "heldout.csv"
    write_measurements(train, twin.measure(q[:n_train], seed=13, meta={"run_id": "hidden"}))
    write_measurements(held, twin.measure(q[n_train:], seed=14))
    return train, held


@pytest.mark.slow
async def test_diagnose_loop_on_hidden_effect_lowers_heldout_error(tmp_path: Path) -> None:
    train, held = hidden_effect_files(tmp_path)
    station = Facade.from_data(train, held, archive_root=tmp_path / "archive", robot_name="ur5-t")
    app = QuickhealthApp(station)
    async with app.run_test(size=(120, 40)) as pilot:
        await pilot.press("5")
        await settle(app, pilot)
        screen = app.screen
        assert app.current_mode == "diagnose"
        diag = screen.diagnosis
        assert diag is not None and diag.verdict == "missing-effect"
        assert diag.candidates[0].effect == "backlash:j2"
        # where the model fails: the per-pose table sorted worst first
        assert screen.query_one("#residuals").row_count == 60
        errs = [r.err_mm for r in diag.residuals]
        first = screen.query_one("#residuals").get_row_at(0)
        assert float(first[1]) == pytest.approx(max(errs), abs=1e-3)
        await pilot.press("s")  # by pose
        await pilot.pause()
        assert screen.query_one("#residuals").get_row_at(0)[0] == diag.residuals[0].pose_id
        # add the chosen (top) effect: background refit, before/after side by side
        await pilot.press("a")
        await settle(app, pilot)
        refit = screen.refit
        assert refit is not None, text(app, "#before-after")
        assert refit.effects_after == ("backlash:j2",)
        assert refit.after_mm < 0.7 * refit.before_mm
        shown = text(app, "#before-after")
        assert "Held-out error" in shown
        assert f"{refit.before_mm:.3f}" in shown and f"{refit.after_mm:.3f}" in shown
        # the model now has the effect; the new diagnosis no longer asks for it
        assert "backlash:j2" in text(app, "#diag-verdict")
        assert all(c.effect != "backlash:j2" for c in screen.diagnosis.candidates)
        assert (station.run_dir / "refit_backlash_j2.png").is_file()


@pytest.mark.slow
async def test_results_history_and_ui_live_while_the_fit_runs(tmp_path: Path) -> None:
    train, held = hidden_effect_files(tmp_path, n_train=60, n_held=10)
    station = Facade.from_data(train, held, archive_root=tmp_path / "archive", threshold_mm=5.0)
    app = QuickhealthApp(station)
    async with app.run_test(size=(120, 40)) as pilot:
        await pilot.press("4")  # Results: starts the fit (a worker, the fit in a child process)
        await pilot.pause()
        fit = [w for w in app.workers if w.group == "fit"]
        assert fit and fit[0].state in (WorkerState.PENDING, WorkerState.RUNNING)
        # keys are answered while the fit computes: count those handled with the fit running
        handled = 0
        while fit[0].state is WorkerState.RUNNING and handled < 5:
            before = app.screen.motion
            await pilot.press("m")  # next error motion of the curve plot
            if fit[0].state is WorkerState.RUNNING:
                assert app.screen.motion == (before + 1) % 6
                handled += 1
        assert handled >= 2, "the UI did not answer while the fit ran"
        await pilot.press("6")  # a screen switch
        await pilot.pause()
        assert app.current_mode == "history"
        await settle(app, pilot)
        await pilot.press("4")
        await settle(app, pilot)
        h = app.screen.health
        assert h is not None and h.n_poses == 60
        # below the threshold, but the report's verdict (the one every door gives) counts
        # the effect the model misses: degraded, and why
        assert 0 < h.mean_mm < h.max_mm < 5.0
        assert h.verdict == "degraded" and "backlash:j2" in h.reason, h.reason
        summary = text(app, "#summary")
        assert "DEGRADED" in summary and f"max {h.max_mm:.3f} mm" in summary
        assert len(h.worst) >= 3 and h.worst[0].err_mm >= h.worst[-1].err_mm
        for name in ("model.json", "report.json", "workspace_error.png", "joint_curves.png"):
            assert (station.run_dir / name).is_file(), name
        await pilot.press("j")  # next joint in the curve plot
        assert app.screen.joint == 1
        assert text(app, "#curve-title").startswith("j2")
        await pilot.press("6")
        await settle(app, pilot)
        hist = app.screen.history
        assert [r.run_id for r in hist.rows] == ["hidden"]
        # judged degraded (its model misses an effect), it is still the robot's baseline: the
        # first run is the reference later runs are compared with, whatever its verdict says
        assert hist.rows[0].verdict == "degraded" and hist.rows[0].baseline
        assert hist.latest[0].startswith("DEGRADED: the error model misses a physical effect")
        assert app.screen.query_one("#runs").row_count == 1
        assert (station.run_dir / "trend.png").is_file()
