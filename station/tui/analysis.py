"""Fit, results, diagnosis and refit of one data set, for the technician's screens: the
:class:`Analysis` the facade holds for the current run's measurements."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...identify.assess import Assessment
from ...identify.diagnose import Diagnosis as Diagnosed
from ...identify.errormodel import MOTION_WORDS, MOTIONS
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.robot import RobotModel
from ..reporting.verdict import Judgement, ThresholdFigure
from ..services.options import FitOptions
from . import jobs
from .offload import offload
from .views import Candidate, Diagnosis, Health, JointCurve, PoseResidual, Refit

MOTION_UNITS = {"dx": "mm", "dy": "mm", "dz": "mm", "ex": "mrad", "ey": "mrad", "ez": "mrad"}


@dataclass
class _Model:
    """The current assessment of the current data (mutable session state, not a result)."""

    assessment: Assessment
    effects: tuple[str, ...]
    n_poses: int


def _slug(name: str) -> str:
    return name.replace(":", "_")


class Analysis:
    """Fit, results, diagnosis and refit of one data set (a run's measurements).

    ``heldout`` is data of the same robot and set-up the fit never sees (e.g. a second
    measurement file); without it the before/after comparison cross-validates the run.
    ``out_dir``, when set, receives the PNG figures.  ``source`` is the measurement file (the
    report's ``input``).  The fit's options are every door's (:class:`FitOptions`) but for
    ``max_order`` and the effects added here.
    """

    def __init__(
        self,
        robot: RobotModel,
        meas: Measurements,
        heldout: Measurements | None = None,
        *,
        max_order: int = FitOptions.max_order,
        effects: tuple[str, ...] = (),
        source: str | Path | None = None,
    ) -> None:
        self.robot = robot
        self.meas = meas
        self.heldout = heldout
        self.max_order = max_order
        self.effects = tuple(effects)
        self.source = None if source is None else str(source)
        self._lock = threading.Lock()
        self._model: _Model | None = None
        self._diag: tuple[tuple[int, int], Diagnosed] | None = None
        self.out_dir: Path | None = None

    @property
    def options(self) -> FitOptions:
        """The options of the current fit."""
        return FitOptions(effects=self.effects, max_order=self.max_order)

    # ----- fitting ---------------------------------------------------------------------------
    def assess(self, effects: tuple[str, ...] | None = None) -> Assessment:
        """The assessment (BIC order selection, ML fit, workspace, curves) with ``effects``
        (default: the current ones), as ``identify fit`` runs it
        (:func:`~quickhealth.station.services.fitting.assess`)."""
        opts = self.options if effects is None else replace(self.options, effects=effects)
        return offload(jobs.assess_job, self.robot, self.meas, opts)

    def assessment(self) -> Assessment:
        """The current assessment of all the data (once, again when effects or data change)."""
        with self._lock:
            m = self._model
            if m is None or m.effects != self.effects or m.n_poses != self.meas.n_poses:
                m = _Model(self.assess(), self.effects, self.meas.n_poses)
                self._model = m
            return m.assessment

    def model(self) -> FittedModel:
        """The current model of all the data (the assessment's fitted model)."""
        return self.assessment().fitted

    # ----- screens ---------------------------------------------------------------------------
    def health(self, *, run_id: str, robot_name: str, judgement: Judgement) -> Health:
        """The health summary of the current model, with the verdict of its report."""
        a = self.assessment()
        fitted, ws = a.fitted, a.workspace
        worst = offload(jobs.regions_job, fitted)
        curves = []
        for jc in a.curves:
            for m, motion in enumerate(MOTIONS):
                if not np.any(jc.values[m]) and not np.any(jc.half_width[m]):
                    continue  # not in the model
                curves.append(
                    JointCurve(
                        joint=f"j{jc.joint}",
                        motion=motion,
                        words=MOTION_WORDS[motion],
                        unit=MOTION_UNITS[motion],
                        q_deg=np.degrees(jc.theta),
                        value=jc.values[m] * 1e3,
                        band=jc.half_width[m] * 1e3,
                    )
                )
        base = judgement.baseline
        return Health(
            run_id=run_id,
            robot=robot_name,
            mean_mm=ws.mean * 1e3,
            std_mm=ws.std * 1e3,
            max_mm=ws.max * 1e3,
            spec_mm=None if judgement.spec is None else judgement.spec.mm,
            spec_figure=ThresholdFigure.MAX if judgement.spec is None else judgement.spec.figure,
            verdict=judgement.verdict,
            reason=judgement.reason,
            verdict_lines=judgement.lines(),
            baseline_mean_mm=None if base is None or judgement.this_is_baseline else base.mean_mm,
            hist_counts=tuple(int(c) for c in ws.hist_counts),
            hist_edges_mm=tuple(float(e) * 1e3 for e in ws.hist_edges),
            curves=tuple(curves),
            worst=worst,
            rms_pos_mm=float(fitted.rms_pos * 1e3),
            n_poses=self.meas.n_poses,
            effects=tuple(e.name for e in fitted.effects),
        )

    def diagnose(self) -> Diagnosis:
        """Residuals per pose and the ranked candidate effects of the current model."""
        fitted = self.model()
        key = (id(fitted), self.meas.n_poses)
        if self._diag is None or self._diag[0] != key:
            self._diag = (key, offload(jobs.diagnose_job, fitted, self.meas))
        diag = self._diag[1]
        # measured and model positions in the robot base frame (the registered base), mm
        T_ib = fitted.registration[0]
        res = fitted.residual_pos @ T_ib[:3, :3] * 1e3  # measured − model
        pos = (self.meas.pos - T_ib[:3, 3]) @ T_ib[:3, :3] * 1e3
        ids = self.meas.pose_id or tuple(f"p{i:04d}" for i in range(self.meas.n_poses))
        residuals = tuple(
            PoseResidual(
                pose_id=ids[i],
                measured_mm=tuple(float(v) for v in pos[i]),  # type: ignore[arg-type]
                model_mm=tuple(float(v) for v in pos[i] - res[i]),  # type: ignore[arg-type]
                err_mm=float(np.linalg.norm(res[i])),
            )
            for i in range(self.meas.n_poses)
        )
        cands = tuple(
            Candidate(c.effect, float(c.score), float(c.predicted_rms_drop_mm), c.evidence)
            for c in diag.candidates[:12]
            if c.significant or len(diag.candidates) <= 12
        )
        return Diagnosis(str(diag.verdict.value), self.effects, residuals, cands)

    def add_effect(
        self, effect: str, on_step: Callable[[int, int, str], None] | None = None
    ) -> Refit:
        """Fit without and with ``effect``; held-out (or cross-validated) error before and after.

        The effect then stays in the model, so the next diagnosis looks for what is still
        missing.  ``on_step(done, total, what)`` reports each fit.
        """
        step = on_step or (lambda done, total, what: None)
        folds = 5
        total = 2 if self.heldout is not None else 2 + 2 * folds
        done = [0]

        def progress(line: str) -> None:
            done[0] = min(done[0] + 1, total)
            step(done[0], total, line)

        step(0, total, f"fitting with {effect}…")
        png = None if self.out_dir is None else str(self.out_dir / f"refit_{_slug(effect)}.png")
        cmp = offload(
            jobs.compare_job,
            self.model(),
            self.meas,
            effect,
            self.heldout,
            folds,
            png,
            progress=progress,
        )
        after = offload(jobs.evaluate_job, cmp.fitted_after, self.meas)
        with self._lock:
            self.effects = tuple(e.name for e in cmp.fitted_after.effects)
            self._model = _Model(after, self.effects, self.meas.n_poses)
        step(total, total, "done")
        b, a = cmp.before, cmp.after
        return Refit(
            effects_before=self.effects[: -len(cmp.effects)],
            effects_after=self.effects,
            before_mm=b.pos_mm,
            after_mm=a.pos_mm,
            before_axes_mm=(b.x_mm, b.y_mm, b.z_mm),
            after_axes_mm=(a.x_mm, a.y_mm, a.z_mm),
            heldout=f"{cmp.method}, {cmp.n_eval} poses",
        )
