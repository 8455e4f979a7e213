"""Run journal: fsynced appends, CRC per line, torn last line tolerated, other damage refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.journal import (
    JOURNAL,
    SCHEMA,
    Journal,
    iter_records,
    read_journal,
    write_bytes_atomic,
)
from quickhealth.station.provenance import provenance


def _start():
    return {"type": "start", "schema": SCHEMA, "plan_hash": "sha256:" + "0" * 64, "epoch": 0.0}


def _write(tmp_path, n=3):
    with Journal(tmp_path).open() as j:
        j.append(_start())
        for i in range(1, n + 1):
            j.append({"type": "captured", "index": i, "name": f"P{i:03d}", "q_deg": np.arange(6.0)})
            j.append({"type": "measured", "index": i, "name": f"P{i:03d}", "ok": True})
    return tmp_path / JOURNAL


def test_round_trip(tmp_path):
    path = _write(tmp_path)
    st = read_journal(path)
    assert st.start["plan_hash"].startswith("sha256:")
    assert sorted(st.captured) == [1, 2, 3] and sorted(st.measured) == [1, 2, 3]
    assert st.next_index(5) == 4 and st.next_index(3) is None
    assert not st.truncated_tail
    assert st.captured[2]["q_deg"] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert st.start["provenance"] == provenance()  # added by the journal, not by the caller
    assert "provenance" not in st.captured[1]
    with Journal(tmp_path).open() as j:
        j.append({"type": "resume", "done": 3})
    resumed = [r for _, r, _ in iter_records(path) if r["type"] == "resume"]
    assert resumed[0]["provenance"]["software"] == provenance()["software"]


def test_torn_last_line_is_ignored_then_cut_on_reopen(tmp_path):
    path = _write(tmp_path)
    whole = path.read_bytes()
    path.write_bytes(whole + b'{"type":"captured","index":4,"na')  # power cut mid-write
    st = read_journal(path)
    assert st.truncated_tail and 4 not in st.captured
    with Journal(tmp_path).open(truncate_to=st.valid_bytes) as j:
        j.append({"type": "captured", "index": 4, "name": "P004"})
    st2 = read_journal(path)
    assert not st2.truncated_tail and sorted(st2.captured) == [1, 2, 3, 4]
    assert path.read_bytes().startswith(whole)


def test_damage_in_the_middle_is_refused_with_the_line(tmp_path):
    path = _write(tmp_path)
    lines = path.read_bytes().split(b"\n")
    rec = json.loads(lines[2])
    rec["index"] = 7  # edited without updating the checksum
    lines[2] = json.dumps(rec).encode()
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(InputError, match=r"journal.jsonl:3: damaged journal line \(checksum"):
        read_journal(path)


def test_non_finite_values_are_never_written(tmp_path):
    with Journal(tmp_path).open() as j:
        j.append(_start())
        with pytest.raises(ValueError):
            j.append({"type": "captured", "index": 1, "x": float("nan")})
    assert len(read_journal(tmp_path / JOURNAL).captured) == 0


def test_atomic_write_leaves_no_temporary(tmp_path):
    p = tmp_path / "img.png"
    write_bytes_atomic(p, b"abc" * 1000)
    write_bytes_atomic(p, b"xyz")
    assert p.read_bytes() == b"xyz"
    assert [f.name for f in tmp_path.iterdir()] == ["img.png"]
