"""Fit a run's measurements and write what the fit says: every door's fit, in one place.

:func:`assess` is the one call of the assessment (:func:`quickhealth.identify.assess.assess`)
with the options of :class:`~.options.FitOptions`; :func:`write_fit` writes model.json,
report.json, residuals.csv (and the figures) into a folder, atomically: everything goes into a
temporary folder beside it first, so a failure leaves nothing half-written.  :func:`fit_folder`
does both, as ``identify fit`` does; the TUI assesses in a child process and writes with
:func:`write_fit`; ``reprocess`` replaces its whole output folder.

SYNOPSIS::

    res = fit_folder(meas, ur5(), Path("runs/r1"), FitOptions(effects=("thermal",)),
                     source="runs/r1/measurements.csv")
    res.assessment.summary(), res.files.written
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...identify import assess as _assess
from ...identify.errors import InputError
from ...identify.measurements import Measurements
from ...identify.robot import RobotModel
from ..formats import model as model_file
from ..formats import report as report_file
from ..formats.common import write_text_atomic
from ..formats.measurements import check_fit_rows
from ..formats.residuals import residual_table
from ..fsio import (
    foreign_results,
    make_dirs,
    replacing_line,
    result_files,
    write_error,
    write_figure,
)
from ..workers import Pool
from .options import FitOptions

Progress = Callable[[str], None]

#: The files of a fit, in the order they are written.
FIT_FILES = ("model.json", "report.json", "residuals.csv")


@dataclass(frozen=True)
class FitFiles:
    """What :func:`write_fit` wrote.

    ``written``: file names in ``out``; ``replaced``: those that were there before (the
    earlier fit's); ``report``: report.json's content as written (without ``provenance``).
    """

    out: Path
    written: tuple[str, ...]
    replaced: tuple[str, ...]
    report: dict[str, Any]


@dataclass(frozen=True)
class FitResult:
    """The assessment of a folder's data and the files written."""

    assessment: _assess.Assessment
    files: FitFiles
    replacing: str  # the one line about replaced files ("" when nothing was replaced)


def assess(
    meas: Measurements,
    robot: RobotModel,
    options: FitOptions = FitOptions(),
    *,
    progress: Progress | None = None,
) -> _assess.Assessment:
    """The assessment of ``meas`` on ``robot`` with ``options`` (the one call every door
    makes; the fit's row limit, :func:`~..formats.measurements.check_fit_rows`, holds for
    every door: ``reprocess``, the TUI, ``identify fit``)."""
    check_fit_rows(meas, "the measurements")
    return _assess.assess(
        meas,
        robot,
        list(options.effects),
        noise=options.noise,
        prior=options.prior,
        max_order=options.max_order,
        spec=options.spec,
        margin=options.margin,
        auto_rescale=options.auto_rescale,
        workspace_samples=options.workspace_samples,
        progress=progress,
    )


def fit_folder(
    meas: Measurements,
    robot: RobotModel,
    out: Path,
    options: FitOptions = FitOptions(),
    *,
    source: str | Path | None = None,
    plots: bool = False,
    forced: str = "",
    progress: Progress | None = None,
    spec: Mapping[str, Any] | None = None,
) -> FitResult:
    """Assess ``meas`` and write the fit into ``out`` (see the module docstring).

    Parameters
    ----------
    source : path, optional
        The measurement file, recorded as report.json's ``input`` and named in errors.
    plots : bool
        Also write the PNG figures (workspace histogram, residuals, each joint's curves).
    forced : str
        What ``--force`` overrode in ``out`` (:func:`claim_fit_folder`), for the line.
    spec : mapping, optional
        The accuracy spec (:meth:`~..reporting.verdict.Spec.as_dict`), recorded in
        report.json's ``spec`` for every verdict.

    Raises
    ------
    InputError
        The data cannot be assessed (too few poses, an effect's column missing …), named
        with the source file.
    """
    render = FigureRenderer() if plots else None  # its workers import matplotlib meanwhile
    try:
        a = assess(meas, robot, options, progress=progress)
    except InputError as exc:
        if render is not None:
            render.close()
        raise _with_source(exc, source) from None
    files = write_fit(out, a, source=source, render=render, spec=spec)
    line = replacing_line(out, files.replaced, "the earlier fit of this data", forced)
    return FitResult(a, files, line)


def write_fit(
    out: Path,
    a: _assess.Assessment,
    *,
    source: str | Path | None = None,
    render: FigureRenderer | None = None,
    extra: Mapping[str, str] | None = None,
    whole_folder: bool = False,
    spec: Mapping[str, Any] | None = None,
) -> FitFiles:
    """Write model.json, report.json and residuals.csv of assessment ``a`` into ``out``.

    Parameters
    ----------
    render : FigureRenderer, optional
        Also draw the PNG figures (it is closed when done).
    extra : mapping of file name to text, optional
        More files written with the fit (reprocess.json, a re-detected measurements.csv).
    whole_folder : bool
        ``out`` is the fit's own folder (``reprocess``): it is replaced as a whole, by one
        rename.  Otherwise (a run folder holds the run's files too) each file is replaced.
    """
    make_dirs(out.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=".fit-", dir=out.parent))
    except OSError as exc:
        if render is not None:
            render.close()
        raise write_error(out, exc) from None
    try:
        if render is not None:
            render.run(a, tmp)
        model_file.write_model(tmp / "model.json", a.fitted)
        doc = report_file.write_report_json(
            tmp / "report.json",
            a,
            source=None if source is None else str(source),
            extra=None if spec is None else {"spec": dict(spec)},
        )
        write_text_atomic(tmp / "residuals.csv", residual_table(a.fitted, a.measurements))
        for name, text in (extra or {}).items():
            write_text_atomic(tmp / name, text)
        names = tuple(sorted(f.name for f in tmp.iterdir()))
        if whole_folder:
            replaced = names if out.is_dir() else ()
            if out.exists():
                shutil.rmtree(out)
            tmp.rename(out)
        else:
            make_dirs(out)
            replaced = tuple(n for n in names if (out / n).exists())
            for n in names:
                (tmp / n).replace(out / n)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return FitFiles(out, names, replaced, doc)


def claim_fit_folder(out: Path, meas: Path) -> tuple[bool, list[str]]:
    """Whose is the output folder of ``identify fit MEAS --out DIR``?

    Returns whether ``DIR`` holds the input ``MEAS`` itself (the run folder of this data: its
    plan, journal, images and measurements are this run's), and what in ``DIR`` belongs to
    another kind or run (for :func:`~quickhealth.station.fsio.claim_output_folder`): outside
    the data's own folder a plan or a run's files, anywhere a fit whose report.json names
    another input file (or, outside the own folder, a fit that names none).
    """
    if not out.is_dir():
        return False, []
    try:
        own = meas.is_file() and os.path.samefile(meas.parent, out)
    except OSError:
        own = False
    other = [] if own else foreign_results(out, "fit")
    fit = [n for n in result_files(out)["fit"] if n in ("model.json", "report.json")]
    if fit:
        src = None
        if (out / "report.json").is_file():
            try:
                doc = report_file.read_report(out / "report.json")
                src = doc.get("input") if isinstance(doc.get("input"), str) else None
            except InputError:
                src = None
        if src is None:
            if not own:
                other.append(f"a fit of unknown data ({', '.join(fit)})")
        elif not _same_input(Path(src), meas, own):
            other.append(f"the fit of another measurement file, {src} ({', '.join(fit)})")
    return own, other


def _same_input(recorded: Path, meas: Path, own_folder: bool) -> bool:
    """Is the input a report.json records (as typed then) the file ``meas``?"""
    try:
        if recorded.is_file() and os.path.samefile(recorded, meas):
            return True
    except OSError:
        pass
    # typed from another working directory: in the data's own folder the name tells
    return own_folder and recorded.name == meas.name


def _with_source(exc: InputError, source: str | Path | None) -> InputError:
    """The assessment's error named with the measurement file (its last line for too few
    poses: the file ends too soon)."""
    if source is None:
        return exc
    if "too few" not in str(exc):
        return InputError(f"{source}: {exc}")
    n_lines = len(Path(source).read_text(encoding="utf-8").splitlines())
    return InputError(f"{source}:{n_lines}:1: {exc}")


# --------------------------------------------------------------------------- figures


def _render_figure(job: tuple[str, Any, Any, str]) -> str:
    """One PNG of ``identify fit --plots`` (runs in a worker process)."""
    from ...identify import report  # matplotlib: loaded by the workers only

    kind, data, extra, path = job
    if kind == "workspace":
        fig = report.workspace_histogram(data)
    elif kind == "residuals":
        fig = report.residual_plot(data, extra)
    else:
        fig = report.joint_curve_figure(data)
    return write_figure(fig, path, dpi=100)


def _warm() -> None:
    from ...identify import report  # noqa: F401  (matplotlib, while the parent fits)


class FigureRenderer:
    """The PNGs of a fit drawn by two worker processes: they import matplotlib while the fit
    runs, then draw one figure each at a time (8 figures, ~0.3 s each)."""

    def __init__(self) -> None:
        ctx = multiprocessing.get_context("fork")
        self.pool = Pool(max_workers=2, mp_context=ctx)  # its workers end with the command
        self.warm = [self.pool.submit(_warm) for _ in range(2)]

    @staticmethod
    def names(n_joints: int) -> list[str]:
        """The files it writes for a robot of ``n_joints``."""
        return ["workspace_histogram.png", "residuals.png"] + [
            f"joint{j}_curves.png" for j in range(1, n_joints + 1)
        ]

    def run(self, a: _assess.Assessment, out: Path) -> None:
        """Draw every figure of ``a`` into ``out`` (then the workers end)."""
        jobs = [("workspace", a.workspace, None, str(out / "workspace_histogram.png"))]
        jobs += [("curves", c, None, str(out / f"joint{c.joint}_curves.png")) for c in a.curves]
        jobs.insert(1, ("residuals", a.fitted, a.measurements, str(out / "residuals.png")))
        try:
            list(self.pool.map(_render_figure, jobs))
        finally:
            self.close()

    def close(self) -> None:
        """Stop the workers."""
        self.pool.shutdown(wait=True, cancel_futures=True)
