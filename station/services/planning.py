"""Plan a cell's fixed loop and write it: plan.json, loop.script and the Fig. 6 plots.

:func:`plan_folder` is ``quickhealth plan`` without its words: the planner's steps 1–5, the
plan validated as the frozen document a run will load, its URScript program made from that
document, everything written into one folder (each file atomically) after the planning work.

SYNOPSIS::

    res = plan_folder(load_cell("reference"), 150, 0, Path("plan"))
    res.result.summary(), res.plan.hash

:func:`select_rows` is ``quickhealth plan select``: the rows of a file of candidate joint
configurations an optimal design chooses (:mod:`quickhealth.identify.design`).
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ...identify.design import (
    DesignPrior,
    DesignResult,
    DesignSettings,
    prior_from_baseline,
    select_poses,
)
from ...identify.errors import InputError
from ...identify.robot import RobotModel
from ..formats.common import csv_cell, csv_text, read_text_limited
from ..formats.measurements import parse_measurements
from ..fsio import claim_output_folder, foreign_results, make_dirs, replacing_line, write_atomic
from ..planning.cell import Cell
from ..planning.figures import write_figures
from ..planning.iso_cube import with_iso_cycles
from ..planning.planfile import Plan, dumps, plan_from_dict, plan_to_dict
from ..planning.planner import PlanResult, plan_loop
from ..planning.urscript import render_urscript

#: The files of a plan folder.
PLAN_FILES = ("plan.json", "loop.script", "fig6_joints.png", "fig6_targets.png")


@dataclass(frozen=True)
class PlanFiles:
    """What :func:`plan_folder` planned and wrote (``replacing``: the line about files it
    replaced, "" when none)."""

    result: PlanResult
    plan: Plan
    paths: tuple[Path, ...]
    replacing: str


def plan_folder(
    cell: Cell,
    n_candidates: int,
    seed: int,
    out: Path,
    *,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    optimal: int | None = None,
    design_prior: DesignPrior | None = None,
    iso_cycles: int | None = None,
    check: Callable[[PlanResult], None] | None = None,
) -> PlanFiles:
    """Plan ``cell`` from ``n_candidates`` random targets (``seed``) and write the plan to ``out``.

    ``optimal``: keep this many of the feasible targets by the optimal design
    (``plan --optimal K``, :mod:`quickhealth.station.planning.optimal`), with ``design_prior``
    (``--baseline``, :func:`baseline_prior`; default the stated prior).  ``iso_cycles``: add
    the ISO 9283 cube's five poses, visited that many times after the loop (``plan
    --iso9283``, :mod:`quickhealth.station.planning.iso_cube`).  ``check``: called with the
    plan before anything is written; it refuses a plan by raising (``plan --strict``).

    Raises
    ------
    InputError
        ``out`` holds another plan, a run or a fit (unless ``force``); checked again after
        planning, when the new plan's hash is known.
    """
    foreign = foreign_results(out, "plan")
    claim_output_folder(out, foreign, force=force)  # before the planning work
    res = plan_loop(cell, n_candidates, seed, progress, optimal=optimal, design_prior=design_prior)
    if iso_cycles:
        res = with_iso_cycles(res, iso_cycles)
    if check is not None:
        check(res)
    doc = plan_to_dict(res)
    plan = plan_from_dict(doc, "plan.json")  # the program is made from the validated document
    script = render_urscript(plan)
    other = _other_plan(out / "plan.json", doc["hash"])
    forced = claim_output_folder(out, foreign + other, force=force)
    replaced = [n for n in PLAN_FILES if (out / n).exists()]
    said = replacing_line(out, replaced, "the same plan" if "plan.json" in replaced else "", forced)
    make_dirs(out)
    write_atomic(out / "plan.json", dumps(doc).encode("utf-8"), durable=True)
    write_atomic(out / "loop.script", script.encode("utf-8"), durable=True)
    figs = write_figures(res, out)
    return PlanFiles(res, plan, (out / "plan.json", out / "loop.script", *figs), said)


def _other_plan(path: Path, new_hash: str) -> list[str]:
    """Why ``path`` (an existing plan.json) is another plan than the one of ``new_hash``
    (runs and the trend compare plans by hash: replacing a different plan is not silent)."""
    if not path.exists():
        return []
    try:
        old = json.loads(path.read_text(encoding="utf-8")).get("hash")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        return [f"a plan.json that cannot be read ({path.name})"]
    if old == new_hash:
        return []
    return [f"another plan ({path.name} {str(old)[:19]}..., this one {new_hash[:19]}...)"]


# --------------------------------------------------------------------------- plan select


def baseline_prior(folder: Path, robot: RobotModel) -> DesignPrior:
    """The design's prior from a fitted baseline run folder (``--baseline RUN_DIR``): its
    model's orders, sizes, effects and residual scatter
    (:func:`~quickhealth.identify.design.prior_from_baseline`).

    Raises
    ------
    InputError
        Not a fitted run folder (one line, as ``check --baseline`` says it), or a fit of
        another arm than ``robot``.
    """
    from .checking import load_baseline  # the check's service: its one reading of a baseline

    base = load_baseline(folder)
    fr = base.fitted.robot
    if fr.n_joints != robot.n_joints or fr.name.lower() != robot.name.lower():
        raise InputError(
            f"--baseline {folder}: a fit of {fr.name} ({fr.n_joints} joints), not of "
            f"{robot.name} ({robot.n_joints} joints)"
        )
    sha = base.model_sha256[:12]
    return prior_from_baseline(base.fitted, f"baseline {base.run_id} (model sha256:{sha}…)")


@dataclass(frozen=True)
class Selection:
    """What :func:`select_rows` chose: the rows (0-based, in the file's order), the file's
    lines to write, and the design's figures."""

    rows: tuple[int, ...]
    text: str
    result: DesignResult


def select_rows(
    candidates: Path,
    robot: RobotModel,
    n: int,
    settings: DesignSettings,
) -> Selection:
    """Choose ``n`` rows of a joint table (CSV v1 ``q1 … qN`` columns, deg) by the design's
    criterion (:func:`~quickhealth.identify.design.select_poses`); only the joint columns are
    read, every row chosen is written back as it was (all its columns, the file's comments
    and header first), in the file's order.

    Raises
    ------
    InputError
        A file that is not a joint table (one line, file:line:column), ``n`` out of range.
    """

    text = read_text_limited(candidates, "candidates")
    meas = parse_measurements(text, str(candidates), robot.n_joints, joints_only=True)
    res = select_poses(robot, meas.q, n, settings)
    lines = [ln for ln in text.splitlines() if ln.strip()]
    head = [ln for ln in lines if ln.strip().startswith("#")]
    body = [ln for ln in lines if not ln.strip().startswith("#")]
    header, data = body[0], body[1:]
    if len(data) != meas.n_poses:  # pragma: no cover - the parser read the same lines
        raise InputError(f"{candidates}: {len(data)} rows, the parser read {meas.n_poses}")
    rows = tuple(sorted(int(i) for i in res.indices))
    # the chosen rows with all their columns, each text cell neutralised for spreadsheets
    # (the file may hold =HYPERLINK(...) pose ids; read back, they are what they were)
    head = [",".join([c[0], *(csv_cell(csv_text(x)) for x in c[1:])]) for c in (h.split(",") for h in head)]  # fmt: skip
    chosen = []
    for i in rows:
        line = data[i]
        cells = next(csv.reader([line])) if '"' in line else line.split(",")
        neutral = [csv_cell(csv_text(c)) for c in cells]
        if neutral == cells:
            chosen.append(line)  # as it was (a quoted '#' first cell stays quoted)
            continue
        buf = io.StringIO()
        csv.writer(buf, lineterminator="", quoting=csv.QUOTE_ALL).writerow(neutral)
        chosen.append(buf.getvalue())
    note = (
        f"# selected: {n} of {meas.n_poses} rows by the {settings.criterion.value}-optimal "
        f"design (quickhealth plan select; {res.n_information} by information, "
        f"{res.n_spread} to represent the candidates; prior: {res.prior_source}); predicted "
        f"TCP band {res.band_mm:.4f} mm rms, random {n}: {res.random_band_mm:.4f} mm"
    )
    out = "\n".join([*head, note, header, *chosen]) + "\n"
    return Selection(rows, out, res)
