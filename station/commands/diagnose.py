"""``quickhealth diagnose`` and ``quickhealth twin``.

quickhealth diagnose DIR/model.json MEAS.csv --json OUT.json [--plots DIR] [--fail-on-missing]
    Which physical effect does the model miss?  OUT.json (CONTRACTS.md):
    {"verdict": "adequate" | "missing-effect", "candidates": [{"effect", "score",
    "predicted_rms_drop_mm", "evidence", ...}, ...]}, best first.  Exit 0 for either
    verdict; 1 for "missing-effect" with --fail-on-missing; 2 bad input.

quickhealth twin --out MEAS.csv [--effects NAME=SIZE,...] [--n N] [--seed S] [--heldout N2]
    Measurements of the digital twin (a UR5 with random errors and hidden effects, seen by
    a camera 2 m away) as CSV v1, and its truth as JSON beside it.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.diagnose import Verdict, plot_candidate, plot_spectrum
from ...identify.effects import effect_type, effect_types, parse_effect
from ...identify.errors import InputError
from ...identify.robot import RobotModel, ur5
from ...identify.twin import joint_schedules, make_twin, payloads, random_joints, schedules
from .. import options, workers
from ..formats import (
    check_fit_rows,
    check_joint_limits,
    read_measurements,
    read_model,
    write_measurements,
    write_text_atomic,
)
from ..fsio import refuse_overwriting_inputs, write_figure
from ..progress import Progress
from ..services.diagnosis import diagnose_model, write_diagnosis

F = NDArray[np.float64]


def size_units() -> str:
    """The units of effect sizes on the command line (the twin's --effects NAME=SIZE), as
    each effect type declares them (:class:`~quickhealth.identify.effects.TwinSize`)."""
    return "; ".join(f"{t.doc}: {t.twin.unit}" for t in effect_types() if t.twin is not None)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "diagnose",
        help="which physical effect does the model miss?",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("model", type=Path, help="DIR/model.json from identify fit")
    p.add_argument("meas", type=Path, help="measurement CSV v1 (the fitted data or new data)")
    p.add_argument("--json", type=Path, required=True, help="write the diagnosis here")
    p.add_argument("--plots", type=Path, help="folder for the figures (top candidates, spectrum)")
    p.add_argument(
        "--fail-on-missing",
        action="store_true",
        help="exit status 1 when an effect is missing",
    )
    p.add_argument(
        "--top", type=options.TOP, default=5, help="candidates shown on stdout (default 5)"
    )
    p.add_argument(
        "--alpha",
        type=options.PROBABILITY,
        default=0.01,
        help="family-wise false-alarm rate (default 0.01)",
    )
    p.add_argument(
        "--max-harmonic",
        type=options.HARMONIC,
        default=30,
        help="highest cyclic harmonic tested (default 30)",
    )
    p.add_argument(
        "--candidates",
        help="comma-separated effects to test instead of all (e.g. uniformscale,depthscale)",
    )
    p.add_argument(
        "--quiet", action="store_true", help="no progress on stderr (bar or stage lines)"
    )
    p.set_defaults(func=run_diagnose)

    t = sub.add_parser(
        "twin",
        help="measurements of the digital twin with hidden effects",
        description="Measurements of the digital twin: a UR5 with random geometric and "
        "position-dependent joint errors plus hidden physical effects, measured by a stereo "
        "camera 2 m away (noise 0.03 mm, 0.1 mrad by default). Sizes: "
        + size_units()
        + ". Writes CSV v1 and the truth (JSON, SI units).",
    )
    t.add_argument("--out", type=Path, required=True, help="measurement CSV to write")
    t.add_argument(
        "--effects",
        default="",
        help="hidden effects NAME=SIZE, comma-separated, e.g. backlash:j2=0.02,thermal=2e-5",
    )
    t.add_argument("--n", type=options.TWIN_POSES, default=150, help="poses (default 150)")
    t.add_argument(
        "--plan",
        type=Path,
        help="plan.json: measure its poses (q_deg, in order) instead of random ones",
    )
    t.add_argument("--seed", type=options.SEED, default=0, help="seed of the twin and its data")
    t.add_argument(
        "--heldout",
        type=options.HELDOUT_POSES,
        default=0,
        help="also write N2 held-out poses (OUT.heldout.csv)",
    )
    t.add_argument("--truth", type=Path, help="truth JSON (default OUT with .truth.json)")
    t.add_argument(
        "--sigma-pos-mm", type=options.NOISE_POS_MM, default=0.03, help="instrument noise (mm)"
    )
    t.add_argument(
        "--sigma-rot-mrad", type=options.NOISE_ROT_MRAD, default=0.1, help="instrument noise (mrad)"
    )
    t.add_argument(
        "--sigma-q-deg", type=options.SIGMA_Q_DEG, default=0.0, help="encoder noise (deg)"
    )
    t.add_argument("--duration", type=options.DURATION_S, default=900.0, help="run duration (s)")
    t.add_argument(
        "--temp-rise", type=options.TEMP_RISE_K, default=6.0, help="warm-up during the run (K)"
    )
    t.add_argument("--position-only", action="store_true", help="no orientation columns")
    t.add_argument(
        "--joint-sensors",
        action="store_true",
        help="also write each joint's temperature and measured torque (temp_j1 …, tau_j1 …; "
        "written anyway when a hidden effect needs them)",
    )
    t.add_argument(
        "--payload-kg",
        type=options.PAYLOAD_KG,
        default=2.0,
        help="the arm picks and places: each pose empty or carrying up to this payload, in the "
        "joint torques (default 2 kg)",
    )
    t.set_defaults(func=run_twin)


def run_diagnose(args: argparse.Namespace) -> int:
    """``quickhealth diagnose`` (:func:`~quickhealth.station.services.diagnosis.diagnose_model`)."""
    workers.keep_freed_memory()  # a batch command: reuse freed arrays (see there)
    if not 0 < args.alpha < 1:
        raise InputError(f"--alpha must be between 0 and 1, got {args.alpha}")
    if args.max_harmonic < 1:
        raise InputError(f"--max-harmonic must be at least 1, got {args.max_harmonic}")
    inputs = [args.model, args.meas]
    refuse_overwriting_inputs([("--json", args.json)], inputs)
    if args.plots is not None:
        _refuse_plots_over_inputs(args.plots, inputs)
    fitted = read_model(args.model)
    meas = read_measurements(args.meas, fitted.robot.n_joints)
    check_fit_rows(meas, args.meas)
    check_joint_limits(meas.q, fitted.robot, str(args.meas))
    cands = None
    if args.candidates:
        cands = [c.strip() for c in args.candidates.split(",") if c.strip()]
    with Progress(quiet=args.quiet) as say:  # a bar on a terminal, stage lines in a log
        d = diagnose_model(
            fitted,
            meas,
            candidates=cands,
            alpha=args.alpha,
            max_harmonic=args.max_harmonic,
            name=str(args.meas),
            progress=say,
            advance=say.advance,
        )
    diag = d.diagnosis
    write_diagnosis(args.json, diag)
    print("\n".join(diag.summary(top=args.top)))
    for s in diag.not_identifiable:  # why a candidate asked about by name was not tested
        if any(s.startswith(f"{c}: ") for c in cands or ()):
            print(s)
    if args.plots:
        for i, c in enumerate(diag.candidates[:3], 1):
            out = args.plots / f"candidate_{i}_{c.effect.replace(':', '_')}.png"
            write_figure(plot_candidate(d.state, meas, c.effect), out, dpi=110)
            print(f"plot: {out}")
        if diag.spectra:
            out = args.plots / "spectrum.png"
            write_figure(plot_spectrum(diag), out, dpi=110)
            print(f"plot: {out}")
    if args.fail_on_missing and diag.verdict is Verdict.MISSING_EFFECT:
        return 1
    return 0


def _refuse_plots_over_inputs(folder: Path, inputs: list[Path]) -> None:
    """--plots DIR writes candidate_*.png and spectrum.png: refuse a DIR where one of those
    names is an input (the names depend on the diagnosis, so by pattern, before any work)."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: --plots must be a folder")
    for i in inputs:
        if fnmatch.fnmatchcase(i.name, "candidate_*.png") or i.name == "spectrum.png":
            refuse_overwriting_inputs([("--plots", folder / i.name)], [i])


def parse_twin_effects(text: str, robot: RobotModel) -> dict[str, float]:
    """``NAME=SIZE,...`` (command-line units, see :func:`size_units`) → SI sizes."""
    out: dict[str, float] = {}
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        name, eq, val = item.partition("=")
        if not eq:
            raise InputError(f"--effects: {item!r} needs a size, e.g. {item}=0.01")
        try:
            size = float(val)
        except ValueError:
            raise InputError(f"--effects: size of {name!r} is not a number: {val!r}") from None
        if not np.isfinite(size):
            raise InputError(f"--effects: size of {name!r} must be finite")
        e = parse_effect(name.strip(), robot)
        twin = effect_type(e.name).twin
        try:  # an effect one size cannot say refuses it, with its reason
            e.twin_params(size * (twin.to_si if twin else 1.0), np.random.default_rng(0))
        except InputError as exc:
            raise InputError(f"--effects: {exc}") from None
        if twin is None:
            raise InputError(f"--effects: {e.name} has no size on the command line")
        out[e.name] = size * twin.to_si
    return out


def _plan_joints(path: Path) -> F:
    """Joint sets (rad) of a plan.json, in execution order."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    try:
        q = np.radians(np.array([p["q_deg"] for p in doc["poses"]], dtype=float))
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{path}: expected {{'poses': [{{'q_deg': [...]}}, ...]}}") from None
    if q.ndim != 2 or q.shape[1] != 6 or q.shape[0] == 0 or not np.all(np.isfinite(q)):
        raise InputError(f"{path}: poses must each have 6 finite joint angles (q_deg)")
    return q


def run_twin(args: argparse.Namespace) -> int:
    """``quickhealth twin``."""
    if args.n < 1 or args.heldout < 0:
        raise InputError("--n must be at least 1 and --heldout not negative")
    if args.sigma_pos_mm < 0 or args.sigma_rot_mrad < 0 or args.sigma_q_deg < 0:
        raise InputError("noise levels must not be negative")
    effects = parse_twin_effects(args.effects, ur5())
    twin = make_twin(
        seed=args.seed,
        effects=effects,
        sigma_pos=args.sigma_pos_mm * 1e-3,
        sigma_rot=args.sigma_rot_mrad * 1e-3,
        sigma_q=float(np.radians(args.sigma_q_deg)),
    )
    if args.plan:
        q_plan = _plan_joints(args.plan)
        args.n = q_plan.shape[0]
        q_extra = random_joints(
            twin.robot,
            max(args.heldout, 1),
            seed=args.seed + 1,
            T_instr_base=twin.truth.T_instr_base,
        )
        q = np.concatenate([q_plan, q_extra[: args.heldout]])
    else:
        q = random_joints(
            twin.robot,
            args.n + args.heldout,
            seed=args.seed + 1,
            T_instr_base=twin.truth.T_instr_base,
        )
    meta = {"robot": "ur5 (digital twin)", "twin_effects": ",".join(effects) or "none"}
    files = [(args.out, q[: args.n], args.seed + 2)]
    if args.heldout:
        files.append((args.out.with_suffix(".heldout.csv"), q[args.n :], args.seed + 3))
    refuse_overwriting_inputs(
        [("--out", f[0]) for f in files]
        + [("--truth", args.truth or args.out.with_suffix(".truth.json"))],
        [args.plan],
    )
    sensors = args.joint_sensors or any(
        c in ("joint_temp", "joint_torque") for e in twin.effects for c in e.requires()
    )
    if sensors:
        meta["payload"] = f"0 or up to {args.payload_kg:g} kg per pose (joint torques)"
    for path, qq, s in files:
        t, temp = schedules(qq.shape[0], args.duration, args.temp_rise)
        joint = {}
        if sensors:
            load = payloads(qq.shape[0], args.payload_kg, seed=s)
            jt, tau = joint_schedules(twin.robot, qq, t, temp, load)
            joint = {"joint_temp": jt, "joint_torque": tau}
        meas = twin.measure(
            qq, t, temp, seed=s, orientation=not args.position_only, meta=meta, **joint
        )
        write_measurements(path, meas)
        print(f"wrote {path} ({qq.shape[0]} poses)")
    truth_path = args.truth or args.out.with_suffix(".truth.json")
    write_text_atomic(truth_path, json.dumps(twin.truth.to_dict(), indent=1) + "\n")
    print(f"wrote {truth_path}")
    if effects:
        print("hidden: " + ", ".join(f"{k} = {v}" for k, v in twin.truth.effects.items()) + " (SI)")
    else:
        print("hidden: no effect (control)", file=sys.stdout)
    return 0
