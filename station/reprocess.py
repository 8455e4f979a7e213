"""Offline reprocessing of many archived runs: re-detect with a new calibration, refit.

A fleet's archive grows to thousands of runs; a better camera calibration or a new model
version means doing them again.  Each run is one independent job (``reprocess_run``, a plain
function of a frozen :class:`ReprocessJob`, so it pickles to any worker):

1. re-detect (optional, ``calibration`` given): the run's stored stereo images (named in its
   journal) measured again with the new rig (:func:`redetect_run`), giving new measurements;
2. refit: the run's measurements with the archived model's orders and effects (``keep``), or
   a fresh BIC order search (``select``);
3. write ``OUT/model.json``, ``OUT/report.json``, ``OUT/residuals.csv``, the data fitted
   (``OUT/measurements.csv``) and ``OUT/reprocess.json`` (what was done, from which inputs),
   as ``identify fit`` writes a fit (:mod:`quickhealth.station.services.fitting`), and return
   the main figures;
4. with ``report``: the run's report against the archive (the trend with this run's new
   figures), its verdict and the ``run`` object added to ``OUT/report.json``, as
   ``quickhealth report`` adds them (:mod:`quickhealth.station.services.report`).

``reprocess`` runs the jobs in parallel: local processes by default, a Dask cluster when a
scheduler address (or a ``distributed.Client``) is given.  The results are the same either
way (each job is deterministic), in job order.

SYNOPSIS::

    jobs = jobs_for_archive(archive, "ur5-cell3", tag="cal-2026-11")
    results = reprocess(jobs, scheduler="tcp://10.0.0.5:8786")
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..identify.assess import MAX_ORDER, WORKSPACE_SAMPLES
from ..identify.errors import HardwareError, InputError, QuickhealthError
from ..identify.measurements import Measurements
from ..identify.transforms import make_T, rpy_to_R
from ..vision.boards import TargetDescription
from ..vision.pose7d import PoseMeasurement, Rejection, measure_stereo
from . import formats
from .archive import INDEX_FILE, Archive, safe_name
from .formats.journal import Captured
from .formats.vision import read_gray, read_rig
from .hardware.target import T_target_plate, reference_target, target0_from_plate
from .reporting.verdict import HealthVerdict, Spec, ThresholdFigure
from .run.journal import JOURNAL, read_journal
from .services import fitting, report
from .services.options import FitOptions, ReportOptions
from .workers import Pool

F = NDArray[np.float64]


@dataclass(frozen=True)
class ReprocessJob:
    """One run to reprocess (paths absolute, so any worker on the shared file system can do it)."""

    robot: str
    run_id: str
    run_dir: str
    out_dir: str
    calibration: str | None = None  # CAL.json / rig file for re-detection
    orders: str = "keep"  # "keep" the archived model's orders, or "select" anew
    max_order: int = MAX_ORDER
    workspace_samples: int = WORKSPACE_SAMPLES
    report: bool = False  # add the report's sections and verdict to report.json
    spec_mm: float | None = None  # the report's spec instead of the run's (``spec_figure``)
    spec_figure: str = "max"
    archive_root: str | None = None  # the archive of the trend (with ``report``)
    # The index of that archive as it may be shown (its URL without the password; None: the
    # archive's own SQLite file).  A job never carries credentials: a worker reads the URL
    # from its own environment (``$QUICKHEALTH_DB`` or ``$QUICKHEALTH_DB_FILE``,
    # :func:`worker_index_url`) and checks that it names this index.
    archive_index: str | None = None


@dataclass(frozen=True)
class ReprocessResult:
    """What one job produced (figures in mm), or why it failed."""

    robot: str
    run_id: str
    out_dir: str
    ok: bool
    error: str = ""
    redetected: bool = False
    n_poses: int = 0
    rms_pos_mm: float = float("nan")
    figures_mm: dict[str, float] = field(default_factory=dict)
    coeffs: tuple[float, ...] = ()
    verdict: HealthVerdict | None = None  # with the job's ``report``
    reason: str = ""
    fit_as_baseline: bool | None = None  # with ``report``: the archive's healthy flag

    def line(self) -> str:
        """One line for the command line."""
        if not self.ok:
            return f"{self.robot}/{self.run_id}: FAILED: {self.error}"
        f = self.figures_mm
        return (
            f"{self.robot}/{self.run_id}: {self.n_poses} poses, rms {self.rms_pos_mm:.4f} mm; "
            f"workspace mean {f['mean']:.3f} std {f['std']:.3f} max {f['max']:.3f} mm"
            + (" (re-detected)" if self.redetected else "")
            + ("" if self.verdict is None else f"; {self.verdict.upper()}: {self.reason}")
        )


def jobs_for_archive(
    archive: Archive,
    robot: str | None = None,
    *,
    run_ids: Sequence[str] | None = None,
    tag: str = "reprocessed",
    calibration: str | Path | None = None,
    orders: str = "keep",
    max_order: int = MAX_ORDER,
    workspace_samples: int = WORKSPACE_SAMPLES,
    report: bool = False,
    spec: Spec | None = None,
) -> list[ReprocessJob]:
    """Jobs for every run of ``robot`` (or of every robot), output in ``RUN/reprocessed/TAG``;
    with ``report``, each reports its run against ``archive`` (``spec``: instead of the
    run's own accuracy spec)."""
    tag = safe_name(tag, "tag")
    if orders not in ("keep", "select"):
        raise InputError(f"--orders must be keep or select, got {orders!r}")
    cal = None
    if calibration is not None:
        cp = Path(calibration).resolve()
        if not cp.is_file():
            raise InputError(f"{calibration}: calibration file not found")
        cal = str(cp)
    jobs = []
    for r in [robot] if robot else archive.robots():
        for rec in archive.runs(r):
            if run_ids is not None and rec.run_id not in run_ids:
                continue
            folder = archive.folder(rec)
            jobs.append(
                ReprocessJob(
                    robot=rec.robot,
                    run_id=rec.run_id,
                    run_dir=str(folder),
                    out_dir=str(folder / "reprocessed" / tag),
                    calibration=cal,
                    orders=orders,
                    max_order=max_order,
                    workspace_samples=workspace_samples,
                    report=report,
                    spec_mm=None if spec is None else spec.mm,
                    spec_figure=ThresholdFigure.MAX if spec is None else spec.figure,
                    archive_root=str(archive.root) if report else None,
                    archive_index=_shown_index(archive) if report else None,
                )
            )
    if run_ids is not None:
        missing = set(run_ids) - {j.run_id for j in jobs}
        if missing:
            raise InputError(f"runs not in the archive: {', '.join(sorted(missing))}")
    return jobs


def _shown_index(archive: Archive) -> str | None:
    """The archive's index as a job names it: None for its own SQLite file, else the URL
    without its password."""
    from .archive.db import shown

    own = f"sqlite:///{archive.root / INDEX_FILE}"
    return None if archive.url == own else shown(archive.url)


#: The index URL this process was given by the command that started it (a local worker of
#: ``reprocess``: set by :func:`reprocess` in-process and by the pool's initializer).
_local_index_url: str | None = None


def _set_local_index_url(url: str | None) -> None:
    global _local_index_url
    _local_index_url = url


def worker_index_url(expected: str | None) -> str | None:
    """The URL of the index a job names (``expected``: as :func:`_shown_index` shows it), as
    this worker knows it: from the command that started it (local workers), else from its
    own environment (:func:`~.archive.db.index_url`: ``$QUICKHEALTH_DB``, the file
    ``$QUICKHEALTH_DB_FILE``).  None for the archive's own SQLite index.

    Raises
    ------
    InputError
        This worker knows no index URL, or one of another index.
    """
    from .archive.db import URL_ENV, URL_FILE_ENV, index_url, shown

    if expected is None:
        return None
    url = _local_index_url or index_url(None)
    if url is None:
        raise InputError(
            f"the job's index is {expected}, and this worker knows no index URL: set "
            f"{URL_ENV} (or {URL_FILE_ENV}, a file holding it) in the worker's environment "
            "(jobs never carry the password)"
        )
    if shown(url) != expected:
        raise InputError(
            f"the job's index is {expected}, this worker's {URL_ENV} names {shown(url)}: "
            "give the workers the fleet's index"
        )
    return url


def reprocess_run(job: ReprocessJob) -> ReprocessResult:
    """Do one job; failures come back as a result with ``ok=False``, never as an exception."""
    try:
        return _reprocess_run(job)
    except (QuickhealthError, ValueError, OSError) as exc:
        return ReprocessResult(job.robot, job.run_id, job.out_dir, ok=False, error=str(exc))


def redetect_run(
    run_dir: str | Path, calibration: str | Path, target: TargetDescription | None = None
) -> Measurements:
    """Measure a run's stored stereo images again with another camera calibration.

    Reads the journal's captured poses (joint readings, pan angle, time, image files), runs
    the 7D measurement of every stereo pair with the rig of ``calibration`` (search regions
    around the run's old measurement when there is one) and returns the new
    :class:`~quickhealth.identify.measurements.Measurements` in execution order.  Pairs in
    which the target is not found any more are left out (named in ``meta["redetect_failed"]``).

    Raises
    ------
    InputError
        No journal with captured poses, a missing image, or a calibration that is not a stereo
        calibration.
    """
    d = Path(run_dir)
    if not (d / JOURNAL).is_file():
        raise InputError(f"{d}: no {JOURNAL}: the run's images cannot be re-detected")
    st = read_journal(d / JOURNAL)
    if not st.captured:
        raise InputError(f"{d / JOURNAL}: no captured poses to re-detect")
    rig = read_rig(Path(calibration))
    target = reference_target() if target is None else target
    old: dict[str, F] = {}
    if (d / "measurements.csv").is_file():
        m_old = formats.read_measurements(d / "measurements.csv")
        if m_old.pose_id is not None and m_old.rpy is not None:
            T_old = make_T(rpy_to_R(*m_old.rpy.T), m_old.pos)
            old = dict(zip(m_old.pose_id, T_old, strict=True))
    found: list[tuple[Captured, PoseMeasurement]] = []
    failed = []
    for i in sorted(st.captured):
        rec = st.captured[i]
        left, right = (read_gray(d / p, depth=True) for p in rec.images)  # at their depth
        bits = int((rec.camera or {}).get("bits", 8))
        for cam, img in zip(rig.cameras, (left, right), strict=True):
            if tuple(cam.image_size) != (img.shape[1], img.shape[0]):
                raise InputError(
                    f"{calibration}: calibrated for {cam.image_size[0]}×{cam.image_size[1]} px "
                    f"images, the run's are {img.shape[1]}×{img.shape[0]} px"
                )
        hint = old[rec.name] @ T_target_plate(rec.pan) if rec.name in old else None
        deep = bits if bits > 8 else None
        m = measure_stereo(rig, target, left, right, bits=deep, roi_hint=hint, pan=rec.pan)
        if isinstance(m, Rejection) and hint is not None:  # search the whole images
            m = measure_stereo(rig, target, left, right, bits=deep, pan=rec.pan)
        if isinstance(m, Rejection):
            failed.append(rec.name)
            continue
        T0 = target0_from_plate(m.T_left_target, rec.pan)
        found.append((rec, PoseMeasurement(T0, m.cov, m.rms_px, m.n_corners, m.n_outliers)))
    if not found:
        raise InputError(f"{d}: the target was found in none of the images with {calibration}")
    meta = {"redetected_with": str(calibration)}
    if failed:
        meta["redetect_failed"] = " ".join(failed)
    return Measurements(
        q=np.array([c.q for c, _ in found]),
        pos=np.array([m.position for _, m in found]),
        rpy=np.array([m.rpy for _, m in found]),
        time=np.array([c.time_s for c, _ in found], float),
        pan=np.array([c.pan for c, _ in found]),
        sigma_pos=np.array([m.sigma_pos for _, m in found]),
        sigma_rpy=np.array([m.sigma_rpy for _, m in found]),
        pose_id=tuple(c.name for c, _ in found),
        meta=meta,
    )


def _reprocess_run(job: ReprocessJob) -> ReprocessResult:
    src = Path(job.run_dir)
    url = worker_index_url(job.archive_index) if job.report else None  # before the work
    old = formats.read_model(src / "model.json")
    if job.calibration:
        meas = redetect_run(src, job.calibration)
    else:
        meas = formats.read_measurements(src / "measurements.csv", old.robot.n_joints)
    formats.check_fit_rows(meas, str(src / "measurements.csv"))  # the fit's one row limit
    options = FitOptions(
        effects=tuple(e.name for e in old.effects),
        max_order=job.max_order,
        noise=old.noise.stated(),  # the scatter beyond it is estimated anew from this data
        prior=old.prior,
        spec=old.spec if job.orders == "keep" else None,
        workspace_samples=job.workspace_samples,
    )
    a = fitting.assess(meas, old.robot, options)
    done = {"job": asdict(job), "source_model": str(src / "model.json")}
    out = Path(job.out_dir)
    files = fitting.write_fit(
        out,
        a,
        source=str(src / "measurements.csv"),
        extra={
            "measurements.csv": (  # the data as measured, unless detected anew
                formats.format_measurements(meas)
                if job.calibration
                else (src / "measurements.csv").read_text(encoding="utf-8")
            ),
            "reprocess.json": json.dumps(done, indent=1),
        },
        whole_folder=True,
    )
    doc = files.report  # the figures as report.json holds them (mm)
    verdict, reason, fit = None, "", None
    if job.report:
        arch = Archive.open(job.archive_root, url) if job.archive_root else None
        spec = (
            None
            if job.spec_mm is None
            else Spec(job.spec_mm, ThresholdFigure(job.spec_figure), "--threshold-mm")
        )
        j = report.report_run(
            out,
            archive=arch,
            robot=job.robot,
            run_id=job.run_id,
            options=ReportOptions(accuracy_spec=spec, workspace_samples=job.workspace_samples),
            meas=meas,
            write_html=False,
            in_place_of_archived=True,
            record_verdict=False,  # the index keeps the archived run's (--update-index: this)
        ).report.judgement
        verdict, reason, fit = j.verdict, j.reason, j.fit_as_baseline
    return ReprocessResult(
        robot=job.robot,
        run_id=job.run_id,
        out_dir=str(out),
        ok=True,
        redetected=bool(job.calibration),
        n_poses=a.fitted.n_poses,
        rms_pos_mm=doc["rms_pos_mm"],
        figures_mm={k: doc["workspace"][f"{k}_mm"] for k in ("mean", "std", "max")},
        coeffs=tuple(map(float, a.fitted.coeffs)),
        verdict=verdict,
        reason=reason,
        fit_as_baseline=fit,
    )


def reprocess(
    jobs: Sequence[ReprocessJob],
    *,
    scheduler: Any = None,
    workers: int | None = None,
    progress: Callable[[int, int, ReprocessResult], None] | None = None,
    scheduler_timeout_s: float = 10.0,
    index_url: str | None = None,
    security: Any = None,
) -> list[ReprocessResult]:
    """Run the jobs in parallel; results in job order.

    Parameters
    ----------
    jobs : sequence of ReprocessJob
    scheduler : str or distributed.Client, optional
        A Dask scheduler address (``tcp://host:8786``) or a connected client; None runs local
        worker processes.
    workers : int, optional
        Local processes (default: the CPU count, at most the number of jobs; 1 = in this
        process, no pool).
    progress : callable(done, total, result), optional
        Called as each job finishes (in the order they finish).
    scheduler_timeout_s : float
        How long to try to reach the scheduler, and to wait for its first worker (s).
    index_url : str, optional
        The index URL (with its password) for the local workers' reports; never sent to a
        Dask worker, which reads it from its own environment (:func:`worker_index_url`).
    security : distributed.Security, optional
        TLS certificates for the scheduler (:func:`scheduler_security`).

    On a cluster, a job whose worker dies (killed, out of memory, machine lost) is run again
    on another worker by the scheduler; each job is deterministic and writes its output
    folder by a rename, so a retried job leaves one result, as if it had run once.  A job
    that kills three workers comes back as a failed result.

    Returns
    -------
    list of ReprocessResult

    Raises
    ------
    HardwareError
        The Dask scheduler cannot be reached, or has no worker.
    """
    jobs = list(jobs)
    n = len(jobs)
    results: list[ReprocessResult | None] = [None] * n

    def done(i: int, r: ReprocessResult, k: int) -> None:
        results[i] = r
        if progress is not None:
            progress(k, n, r)

    if not jobs:
        return []
    if scheduler is not None:
        _run_dask(jobs, scheduler, done, scheduler_timeout_s, security)
    else:
        w = max(1, min(workers or os.cpu_count() or 1, n))
        if w == 1:
            before = _local_index_url
            _set_local_index_url(index_url)
            try:
                for i, j in enumerate(jobs):
                    done(i, reprocess_run(j), i + 1)
            finally:
                _set_local_index_url(before)
        else:
            with Pool(max_workers=w, initializer=_set_local_index_url, initargs=(index_url,)) as ex:
                futs = {ex.submit(reprocess_run, j): i for i, j in enumerate(jobs)}

                for k, f in enumerate(as_completed(futs), 1):
                    done(futs[f], f.result(), k)
    return [r for r in results if r is not None]


def check_scheduler(address: str) -> None:
    """Refuse (one line, exit 2) a ``--scheduler`` that is not a Dask address, or a plain
    ``tcp://`` one off this machine, before any work starts.  A well-formed address whose
    host does not resolve or answer is a runtime failure, reported when connecting (exit 3).

    Dask workers run the code they are sent, and the jobs name the fleet's archive: a cluster
    that leaves the machine must be ``tls://`` with certificates on every side
    (:func:`scheduler_security`, docs/monitoring.md).
    """
    from distributed.comm import parse_address, resolve_address  # Dask only with --scheduler
    from distributed.comm.addressing import parse_host_port

    try:
        resolve_address(address)
        scheme, loc = parse_address(address)
        host = str(parse_host_port(loc)[0])
    except ValueError as exc:
        raise InputError(
            f"--scheduler {address[:80]!r}: not a Dask scheduler address ({exc}); "
            "e.g. tls://10.0.0.5:8786"
        ) from None
    except OSError:
        return
    if scheme == "tcp" and not _is_loopback(host):
        raise InputError(
            f"--scheduler {address[:80]}: a plain tcp:// cluster off this machine is open to "
            "anyone on the network (Dask workers run the code they are sent): use tls:// with "
            "--tls-ca-file, --tls-cert and --tls-key (docs/monitoring.md)"
        )


def _is_loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def scheduler_security(address: str, ca_file: str | None, cert: str | None, key: str | None) -> Any:
    """Dask's :class:`distributed.Security` for a ``tls://`` scheduler (encryption required;
    the client's certificate and key, the fleet's CA), else None.

    Raises
    ------
    InputError
        A ``tls://`` address without the three files, a file that does not exist, or TLS
        files for a scheduler that is not ``tls://`` (one line).
    """
    given = {"--tls-ca-file": ca_file, "--tls-cert": cert, "--tls-key": key}
    if not address.startswith("tls://"):
        if any(given.values()):
            raise InputError(
                f"--scheduler {address[:80]}: TLS files given for a non-tls:// address"
            )
        return None
    missing = [k for k, v in given.items() if not v]
    if missing:
        raise InputError(
            f"--scheduler {address[:80]}: a tls:// scheduler needs {', '.join(missing)} "
            "(the fleet's CA, this machine's certificate and key)"
        )
    for k, v in given.items():
        if not Path(str(v)).is_file():
            raise InputError(f"{k} {v}: file not found")
    from distributed.security import Security  # Dask (optional) only with --scheduler

    return Security(
        tls_ca_file=ca_file, tls_client_cert=cert, tls_client_key=key, require_encryption=True
    )


def _run_dask(
    jobs: list[ReprocessJob],
    scheduler: Any,
    done: Callable[..., None],
    timeout_s: float,
    security: Any = None,
) -> None:
    from distributed import Client, as_completed  # Dask (optional) only with --scheduler
    from distributed.scheduler import KilledWorker

    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=f"{timeout_s}s", security=security) if own else scheduler
    except ValueError as exc:  # an address that is not one (check_scheduler says so first)
        raise InputError(f"--scheduler {str(scheduler)[:80]!r}: {exc}") from None
    except (OSError, TimeoutError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HardwareError(
            f"cannot reach the Dask scheduler {scheduler}: {msg} "
            "(is `dask scheduler` running there, and the address right?)"
        ) from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except (OSError, TimeoutError):
            raise HardwareError(
                f"the Dask scheduler {scheduler} has no worker after {timeout_s:g} s "
                "(start one: dask worker ADDRESS)"
            ) from None
        futs = client.map(reprocess_run, jobs, pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        for k, f in enumerate(as_completed(futs), 1):
            i = index[f.key]
            try:
                r = f.result()
            except KilledWorker:
                j = jobs[i]
                r = ReprocessResult(
                    j.robot, j.run_id, j.out_dir, ok=False,
                    error="the job killed three Dask workers (out of memory?)",
                )  # fmt: skip
            done(i, r, k)
    finally:
        if own:
            client.close()
