"""Run journal: fsynced appends, CRC per line, torn last line tolerated, other damage refused;
typed records in SI, stored in mm and degrees, through one encoder and one decoder."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.formats.journal import (
    Captured,
    Failed,
    Measured,
    SelfCheck,
    decode,
    encode,
)
from quickhealth.station.provenance import provenance
from quickhealth.station.run.journal import (
    JOURNAL,
    SCHEMA,
    Journal,
    iter_records,
    read_journal,
    write_bytes_atomic,
)


def _start():
    return {"type": "start", "schema": SCHEMA, "plan_hash": "sha256:" + "0" * 64, "epoch": 0.0}


def _captured(i: int) -> Captured:
    q = np.radians(np.arange(6.0))
    return Captured(i, f"P{i:03d}", q, 0.25, 1.5 * i, (f"images/{i}_L.png", f"images/{i}_R.png"))


def _measured(i: int) -> Measured:
    return Measured(
        i, f"P{i:03d}", True, position=np.array([0.1, -0.2, 2.0]), rpy=np.array([0.1, 0.2, 0.3]),
        sigma_pos=np.full(3, 3e-5), sigma_rpy=np.full(3, 1e-4), rms_px=0.2, n_corners=(40, 40),
    )  # fmt: skip


def _write(tmp_path, n=3):
    with Journal(tmp_path).open() as j:
        j.append(_start())
        for i in range(1, n + 1):
            j.append(_captured(i))
            j.append(_measured(i))
    return tmp_path / JOURNAL


def test_round_trip(tmp_path):
    path = _write(tmp_path)
    st = read_journal(path)
    assert st.start["plan_hash"].startswith("sha256:")
    assert sorted(st.captured) == [1, 2, 3] and sorted(st.measured) == [1, 2, 3]
    assert st.next_index(5) == 4 and st.next_index(3) is None
    assert not st.truncated_tail
    assert np.allclose(st.captured[2].q, np.radians(np.arange(6.0)), rtol=0, atol=1e-15)
    assert st.captured[2].pan == pytest.approx(0.25, abs=1e-15)
    assert np.allclose(st.measured[3].position, [0.1, -0.2, 2.0], rtol=0, atol=1e-15)
    assert st.start["provenance"] == provenance()  # added by the journal, not by the caller
    raw = [r for _, r, _ in iter_records(path) if r["type"] == "captured"]
    assert np.allclose(raw[1]["q_deg"], np.arange(6.0), rtol=0, atol=1e-12)  # degrees
    assert "provenance" not in raw[0]
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
        j.append(_captured(4))
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
            j.append(_captured(1).__class__(1, "P001", np.full(6, np.nan), 0.0, 0.0, ("a", "b")))
    assert len(read_journal(tmp_path / JOURNAL).captured) == 0


def test_atomic_write_leaves_no_temporary(tmp_path):
    p = tmp_path / "img.png"
    write_bytes_atomic(p, b"abc" * 1000)
    write_bytes_atomic(p, b"xyz")
    assert p.read_bytes() == b"xyz"
    assert [f.name for f in tmp_path.iterdir()] == ["img.png"]


def test_every_record_round_trips_in_si_and_is_stored_in_mm_and_degrees():
    T = np.eye(4)
    T[:3, 3] = [0.5, -0.25, 1.75]
    records = [
        _captured(1),
        replace(_captured(2), search=((10, 20, 300, 400), (0, 5, 250, 390))),
        _measured(1),
        Measured(2, "P002", False, "target not detected"),
        Failed(3, "P003", "no markers", q=np.radians(np.arange(6.0)), pan=0.5, time_s=9.0),
        SelfCheck("start", True, T_instr_board=T, sigma_pos=np.full(3, 1e-5), rms_px=0.1),
        SelfCheck("end", False, "board not found"),
    ]
    for rec in records:
        obj = json.loads(json.dumps(encode(rec)))
        back = decode(obj)
        assert type(back) is type(rec)
        for k, v in vars(rec).items():
            w = getattr(back, k)
            if isinstance(v, np.ndarray):
                assert np.allclose(w, v, rtol=1e-15, atol=1e-15), k
            else:
                assert w == v, k
    assert "search_px" not in encode(records[0])  # older journals: none, searched anew
    assert encode(records[1])["search_px"] == [[10, 20, 300, 400], [0, 5, 250, 390]]
    sc = encode(records[5])
    assert sc["T_instr_board_mm"][0][3] == 500.0 and sc["sigma_mm"] == [0.01, 0.01, 0.01]
    assert encode(records[2])["x_mm"] == [100.0, -200.0, 2000.0]
    assert encode(records[4])["pan_deg"] == pytest.approx(np.degrees(0.5))


def test_a_record_missing_a_field_is_refused_with_its_line(tmp_path):
    with Journal(tmp_path).open() as j:
        j.append(_start())
        j.append({"type": "captured", "index": 1, "name": "P001"})  # no joints, no images
    with pytest.raises(InputError, match=r"journal.jsonl:2: malformed journal record"):
        read_journal(tmp_path / JOURNAL)
