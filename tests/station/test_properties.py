"""Property tests (hypothesis) of the three readers of user files.

- CSV v1: any text either parses into finite, consistent measurements or is refused with one
  ``InputError`` line; a written file reads back to the same numbers.
- model.json: any mutation of a valid document either reads as a valid, finite model or is
  refused with one ``InputError`` line (never another exception).
- URScript tokenizer: any text either tokenizes or is refused with one ``InputError`` line;
  targets are never found inside comments or strings; replacing targets round-trips.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from quickhealth.identify.errormodel import ErrorModelSpec
from quickhealth.identify.errors import InputError
from quickhealth.identify.fit import InstrumentNoise, fit_model
from quickhealth.identify.measurements import Measurements
from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.identify.urscript import joint_targets, replace_targets, tokenize
from quickhealth.station import formats

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ----------------------------------------------------------------------------- CSV v1

_cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**6), 10**6).map(str),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12),
    st.sampled_from(["", "nan", "inf", "-0", "1e308", "1e-320", '"', ",", "#x"]),
)
_header = st.lists(
    st.sampled_from(
        ["q1", "q2", "q3", "x", "y", "z", "pitch", "yaw", "roll", "time", "pose_id", "sx", "junk"]
    ),
    min_size=1,
    max_size=9,
)


@SETTINGS
@given(header=_header, rows=st.lists(st.lists(_cell, min_size=1, max_size=10), max_size=6))
def test_csv_reader_parses_or_refuses_with_one_line(header, rows):
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
    try:
        m = formats.parse_measurements(text, "f.csv")
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("f.csv")
        return
    assert m.q.shape[0] == m.pos.shape[0] == len(rows) > 0
    assert np.all(np.isfinite(m.q)) and np.all(np.isfinite(m.pos))


@SETTINGS
@given(
    q=st.lists(
        st.lists(st.floats(-170, 170, allow_nan=False), min_size=3, max_size=3),
        min_size=1,
        max_size=8,
    ),
    ids=st.lists(st.text(alphabet="abcXYZ019_-. ,\"'#", min_size=1, max_size=10), max_size=8),
)
def test_csv_writer_and_reader_round_trip(q, ids):
    qa = np.radians(np.array(q))
    n = len(qa)
    assume(np.ptp(qa) > 1.0 or n < 3)  # the reader refuses what looks like radians
    pose_id = tuple(ids[:n]) + tuple(f"P{i}" for i in range(len(ids[:n]), n))
    pos = np.linspace(0.1, 0.2, 3 * n).reshape(n, 3)
    m = Measurements(q=qa, pos=pos, pose_id=tuple(s.strip() for s in pose_id))
    back = formats.parse_measurements(formats.format_measurements(m), "f.csv", 3)
    np.testing.assert_allclose(back.q, m.q, rtol=1e-15, atol=1e-15)  # deg <-> rad
    np.testing.assert_allclose(back.pos, m.pos, rtol=1e-15, atol=1e-18)  # m <-> mm
    assert back.pose_id == m.pose_id


# -------------------------------------------------------------------------- model.json


@pytest.fixture(scope="module")
def model_doc():
    twin = make_twin(seed=2)
    q = random_joints(twin.robot, 40, seed=3, T_instr_base=twin.truth.T_instr_base)
    spec = ErrorModelSpec.uniform(6, 1, twin.robot.q_min, twin.robot.q_max)
    fm = fit_model(twin.robot, twin.measure(q, seed=4), spec, noise=InstrumentNoise(3e-5, 1e-4))
    return formats.model_to_json(fm)


_value = st.one_of(
    st.none(),
    st.booleans(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.text(max_size=5),
    st.lists(st.floats(-1, 1), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)


def _paths(doc, prefix=()):
    """Every (path to a value) in a JSON document, lists sampled at their first and last item."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list) and doc:
        for i in {0, len(doc) - 1}:
            out += _paths(doc[i], (*prefix, i))
    return out


@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_model_reader_reads_a_valid_model_or_refuses_with_one_line(
    model_doc, data, tmp_path_factory
):
    doc = json.loads(json.dumps(model_doc))
    paths = [p for p in _paths(doc) if p]
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths))
        tgt = doc
        try:
            for k in path[:-1]:
                tgt = tgt[k]
            if data.draw(st.booleans()) and isinstance(tgt, dict):
                tgt.pop(path[-1], None)
            else:
                tgt[path[-1]] = data.draw(_value)
        except (KeyError, IndexError, TypeError):
            continue
    p = tmp_path_factory.mktemp("m") / "model.json"
    p.write_text(json.dumps(doc))
    try:
        fm = formats.read_model(p)
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(p))
        return
    assert np.all(np.isfinite(fm.coeffs)) and fm.coeffs.size == fm.spec.n_params
    assert np.all(np.isfinite(fm.robot.links))
    assert np.all(fm.spec.q_hi > fm.spec.q_lo)


# ---------------------------------------------------------------------- URScript tokenizer

_num = st.floats(-3.0, 3.0, allow_nan=False).map(lambda v: f"{v:.6g}")
_joint_list = st.lists(_num, min_size=6, max_size=6).map(lambda v: "[" + ", ".join(v) + "]")
_move = st.builds(
    lambda name, sp, lst, rest: f"{name}{sp}({lst}{rest})",
    st.sampled_from(["movej", "movel", "movep", "servoj"]),
    st.sampled_from(["", " ", "\t"]),
    _joint_list,
    st.sampled_from(["", ", a=1.2, v=0.25", ", t=0.1"]),
)
_noise = st.one_of(
    st.builds(lambda m: f"# {m}", _move),
    st.builds(lambda m: f'textmsg("{m}")', _move),
    st.builds(lambda m: f"popup('{m}')", _move),
    st.sampled_from(["x = 1", "sleep(0.1)", 'textmsg("a # b")', "def f():", "end", "  "]),
)


@SETTINGS
@given(st.lists(st.tuples(st.booleans(), _move, _noise), min_size=1, max_size=8))
def test_tokenizer_finds_exactly_the_real_targets(lines):
    text = ""
    expected = []
    for lineno, (move_first, move, noise) in enumerate(lines, start=1):
        if move_first:
            text += f"{move}  {noise}\n" if not noise.startswith("def") else f"{move}\n"
        else:
            text += (
                f"{noise}; {move}\n" if not noise.lstrip().startswith("#") else f"{move} {noise}\n"
            )
        expected.append(lineno)
    t = joint_targets(text, 6)
    assert t.lines == tuple(expected) and not t.unreadable
    new_q = t.q + 0.001
    out = replace_targets(text, t.spans, new_q)
    t2 = joint_targets(out, 6)
    np.testing.assert_allclose(t2.q, np.round(new_q, 9), atol=1e-9)
    assert t2.lines == t.lines
    # only the lists changed: the rest of the program is the same text
    strip = [text[: t.spans[0][0]]] + [
        text[t.spans[i][1] : t.spans[i + 1][0]] for i in range(len(t.spans) - 1)
    ]
    for piece in strip:
        assert piece in out


@SETTINGS
@given(st.text(max_size=200))
def test_tokenizer_never_fails_other_than_one_input_error_line(text):
    try:
        toks = tokenize(text)
    except InputError as exc:
        msg = str(exc)
        assert "\n" not in msg
        line, col = (int(x) for x in msg.split(":")[:2])
        assert 1 <= line <= text.count("\n") + 1 and col >= 1
        return
    for tk in toks:
        assert text[tk.start : tk.end] == tk.text
    t = joint_targets(text, 6)
    assert t.q.shape == (len(t.lines), 6) and np.all(np.isfinite(t.q))
    assert all(math.isfinite(v) for row in t.q for v in row)
