"""``quickhealth import tracker`` and :mod:`quickhealth.station.formats.tracker`.

The shared UR10 T-Mac series (fixtures/ipa-ur10) checked against an independent read with
scipy, the WAM preset against the old WAM reader's bytes, every layout option on files
written from a known truth, and the one-line refusals.
"""

from __future__ import annotations

import csv
import hashlib
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quickhealth.identify.errors import InputError
from quickhealth.identify.transforms import quat_to_R
from quickhealth.station import formats
from quickhealth.station.cli import main
from quickhealth.station.formats.tracker import (
    PRESETS,
    TrackerLayout,
    euler_rate_matrix,
    layout_with,
    parse_tracker,
    srot_from_euler_sigmas,
)

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
UR10 = FIXTURES / "ipa-ur10" / "measurements_joint_configurations.csv"

#: sha256 of what `identify import-wam FILE --sign S` wrote with the WAM reader before it became
#: the importer's preset (commit 4c7ec52): the preset must write the same bytes
OLD_WAM_SHA256 = {
    ("grid.csv", 1): "c18f20d64f039935a3b06a23b8370020ea2b84ded8b692a0826be8746e20c328",
    ("grid.csv", -1): "630544e4da2fd78f2068bf2ca92640032e90f1868521d661f34cf9e74bb67d49",
    ("random.csv", 1): "5dd3d887d851505ccb060c5cb3184e998dc61c607ccfe941d7334491777ed566",
}

EULER_SEQS = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b and b != c]


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


# ------------------------------------------------------------------ the shared UR10 series


def test_ur10_preset_matches_an_independent_read_with_scipy(tmp_path, capsys):
    out = tmp_path / "ur10.csv"
    assert main(["import", "tracker", str(UR10), "--preset", "ipa-ur10", "--out", str(out)]) == 0
    assert "1495 poses, 6 joints, position and orientation" in capsys.readouterr().out

    # the independent read: the csv module, decimal commas by hand, scipy for the angles
    with UR10.open(newline="") as fh:
        rows = list(csv.reader(fh, delimiter=";"))
    head = rows[0]
    a = np.array([[float(c.replace(",", ".")) for c in r] for r in rows[1:]])

    def col(*names: str) -> np.ndarray:
        return a[:, [head.index(n) for n in names]]

    joints_rad = col(*PRESETS["ipa-ur10"].joints)
    R_ref = Rotation.from_euler(
        "XYZ", col("measurement_rx", "measurement_ry", "measurement_rz"), degrees=True
    ).as_matrix()
    s_ang = col("measurement_std_rx", "measurement_std_ry", "measurement_std_rz")

    text = out.read_text()
    header = next(ln for ln in text.splitlines() if not ln.startswith("#")).split(",")
    assert header[-5:] == ["temp", "sx", "sy", "sz", "srot"]
    assert {"qw", "qx", "qy", "qz"} <= set(header) and "pitch" not in header
    m = formats.read_measurements(out, 6)
    assert m.n_poses == 1495 == len(rows) - 1
    np.testing.assert_allclose(m.q, joints_rad, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        m.pos * 1e3, col("measurement_x", "measurement_y", "measurement_z"), rtol=1e-13
    )
    assert np.abs(m.R - R_ref).max() < 1e-12
    np.testing.assert_allclose(
        m.sigma_pos * 1e3, col("measurement_std_x", "measurement_std_y", "measurement_std_z")
    )
    np.testing.assert_allclose(m.temp, col("measurement_temperature")[:, 0])
    srot = np.degrees(m.sigma_rot)
    # finite and small although yaw (CSV v1's Rz·Ry·Rx) sits within a degree of -90 deg
    yaw = np.degrees(-np.arcsin(np.clip(m.R[:, 2, 0], -1, 1)))
    assert np.abs(yaw + 90).min() < 1.0
    assert np.all(np.isfinite(srot)) and srot.max() < 0.02
    assert 0.002 < np.median(srot) < 0.005
    np.testing.assert_allclose(srot, np.sqrt(np.mean(s_ang**2, axis=1)), rtol=1e-12)
    assert "# instrument: Leica laser tracker with a T-Mac 6-DoF probe" in text


def test_ur10_with_orientation_none_is_position_only(tmp_path):
    out = tmp_path / "p.csv"
    argv = ["import", "tracker", str(UR10), "--preset", "ipa-ur10", "--out", str(out)]
    assert main([*argv, "--orientation", "none"]) == 0
    m = formats.read_measurements(out, 6)
    assert m.rot is None and m.sigma_rot is None and m.sigma_pos is not None


# ------------------------------------------------------------------ the WAM preset


@pytest.mark.parametrize(("name", "sign"), sorted(OLD_WAM_SHA256))
def test_wam_preset_writes_the_old_import_wams_bytes(tmp_path, name, sign):
    src = FIXTURES / "wam" / name
    new, old = tmp_path / "new.csv", tmp_path / "old.csv"
    s = f"{sign:+d}"
    assert main(["import", "tracker", str(src), "--preset", "wam", "--out", str(new)]
                + (["--deviation-sign", s] if sign < 0 else [])) == 0  # fmt: skip
    assert main(["identify", "import-wam", str(src), "--sign", s, "--out", str(old)]) == 0
    assert new.read_bytes() == old.read_bytes()
    assert _sha(new) == OLD_WAM_SHA256[(name, sign)]


# ------------------------------------------------------------------ the Euler-rate map


@pytest.mark.parametrize("seq", EULER_SEQS + [s.upper() for s in EULER_SEQS])
def test_euler_rate_matrix_is_scipys_derivative(seq):
    """Column k of E is the instrument-frame axis of a small change of angle k (all 24)."""
    rng = np.random.default_rng(sum(map(ord, seq)))
    ang = rng.uniform(-2.5, 2.5, size=(5, 3))
    ang[0, 1] = math.pi / 2 if seq[0] != seq[2] else 0.0  # gimbal lock of the sequence
    E = euler_rate_matrix(seq, ang)
    R0 = Rotation.from_euler(seq, ang)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        w = ((Rotation.from_euler(seq, ang + d) * R0.inv()).as_rotvec()) / h
        np.testing.assert_allclose(E[:, :, k], w, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(E, axis=1), 1.0, atol=1e-12)


def test_srot_is_finite_at_gimbal_lock_and_takes_sqrt_trace_over_3():
    sig = np.radians([[0.001, 0.004, 0.002], [0.001, 0.004, 0.002]])
    ang = np.radians([[10.0, 90.0, -30.0], [10.0, 20.0, -30.0]])  # XYZ locks at Y = 90 deg
    s = srot_from_euler_sigmas("XYZ", ang, sig)
    assert np.all(np.isfinite(s))
    np.testing.assert_allclose(s, np.sqrt((sig**2).sum(axis=1) / 3), rtol=1e-12)


# ------------------------------------------------------------------ every option

_TRUTH_N = 6


def _truth(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = _TRUTH_N
    return {
        "q_deg": rng.uniform(-170, 170, (n, 6)),
        "pos_mm": rng.uniform(-3000, 3000, (n, 3)),
        "rot": Rotation.random(n, random_state=seed).as_matrix(),
        "s_pos_mm": rng.uniform(0.005, 0.05, (n, 3)),
        "s_ang_deg": rng.uniform(0.001, 0.01, (n, 3)),
        "temp": rng.uniform(19, 23, n),
        "time": np.arange(n) * 2.5,
    }


def _file(
    t: dict[str, np.ndarray],
    *,
    seq: str = "XYZ",
    sep: str = ",",
    comma: bool = False,
    length: str = "mm",
    joint: str = "deg",
    angle: str = "deg",
    header: list[str] | None = None,
    with_header: bool = True,
) -> str:
    """A tracker export of ``t``: pose, 6 joints, x y z, 3 angles, sigmas, temp, time."""
    lf = {"mm": 1.0, "m": 1e-3, "in": 1 / 25.4}[length]
    q = t["q_deg"] if joint == "deg" else np.radians(t["q_deg"])
    ang = Rotation.from_matrix(t["rot"]).as_euler(seq, degrees=angle == "deg")
    s_ang = t["s_ang_deg"] if angle == "deg" else np.radians(t["s_ang_deg"])
    cols = [f"P{i}" for i in range(len(q))]
    body = np.hstack([q, t["pos_mm"] * lf, ang, t["s_pos_mm"] * lf, s_ang, t["temp"][:, None],
                      t["time"][:, None]])  # fmt: skip
    head = header or (
        ["point"] + [f"J{i}" for i in range(1, 7)] + ["X", "Y", "Z", "A", "B", "C"]
        + ["sX", "sY", "sZ", "sA", "sB", "sC", "T", "time"]
    )  # fmt: skip
    lines = [sep.join(head)] if with_header else []
    for pid, r in zip(cols, body, strict=True):
        cells = [repr(float(v)) for v in r]
        if comma:
            cells = [c.replace(".", ",") for c in cells]
        lines.append(sep.join([pid, *cells]))
    return "\n".join(lines) + "\n"


_MAP = TrackerLayout(
    joints=tuple(f"J{i}" for i in range(1, 7)),
    position=("X", "Y", "Z"),
    orientation=("A", "B", "C"),
    euler="XYZ",
    sigma_position=("sX", "sY", "sZ"),
    sigma_orientation=("sA", "sB", "sC"),
    temp="T",
    time="time",
    pose_id="point",
)


def _check(m, t, seq: str = "XYZ") -> None:
    np.testing.assert_allclose(np.degrees(m.q), t["q_deg"], rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(m.pos * 1e3, t["pos_mm"], rtol=1e-12, atol=1e-9)
    assert np.abs(m.R - t["rot"]).max() < 1e-12
    np.testing.assert_allclose(m.sigma_pos * 1e3, t["s_pos_mm"], rtol=1e-12)
    np.testing.assert_allclose(
        np.degrees(m.sigma_rot), np.sqrt(np.mean(t["s_ang_deg"] ** 2, axis=1)), rtol=1e-12
    )
    np.testing.assert_allclose(m.temp, t["temp"])
    np.testing.assert_allclose(m.time, t["time"])
    assert m.pose_id == tuple(f"P{i}" for i in range(_TRUTH_N))


@pytest.mark.parametrize("seq", EULER_SEQS + [s.upper() for s in EULER_SEQS])
def test_every_euler_convention_as_scipy_names_it(seq):
    t = _truth(1)
    _check(parse_tracker(_file(t, seq=seq), "f.csv", layout_with(_MAP, euler=seq)), t, seq)


@pytest.mark.parametrize(
    ("sep", "option"), [(",", ","), (";", ";"), ("\t", "tab"), (",", "auto"), (";", "auto"),
                        ("\t", "auto")],
)  # fmt: skip
def test_separators_given_or_detected(sep, option):
    t = _truth(2)
    _check(parse_tracker(_file(t, sep=sep), "f", layout_with(_MAP, separator=option)), t)


@pytest.mark.parametrize("sep", [";", "\t"])
def test_decimal_comma(sep):
    t = _truth(3)
    text = _file(t, sep=sep, comma=True)
    _check(parse_tracker(text, "f", layout_with(_MAP, decimal="comma")), t)


@pytest.mark.parametrize("length", ["mm", "m", "in"])
@pytest.mark.parametrize(("joint", "angle"), [("deg", "deg"), ("rad", "rad"), ("rad", "deg")])
def test_units_of_lengths_joints_and_angles(length, joint, angle):
    t = _truth(4)
    text = _file(t, length=length, joint=joint, angle=angle)
    lay = layout_with(_MAP, length_unit=length, joint_unit=joint, angle_unit=angle)
    _check(parse_tracker(text, "f", lay), t)


def test_units_from_the_header_and_columns_by_number():
    t = _truth(5)
    head = ["id"] + [f"J{i} [rad]" for i in range(1, 7)] + ["X [m]", "Y [m]", "Z [m]"]
    head += ["A (deg)", "B (deg)", "C (deg)", "sX [m]", "sY [m]", "sZ [m]", "sA", "sB", "sC"]
    head += ["T [°C]", "time [s]"]
    text = _file(t, length="m", joint="rad", header=head)
    _check(parse_tracker(text, "f", layout_with(_MAP, pose_id="id")), t)  # names without unit
    by_number = layout_with(
        _MAP,
        joints=tuple(str(i) for i in range(2, 8)),
        position=("8", "9", "10"),
        orientation=("11", "12", "13"),
        sigma_position=("14", "15", "16"),
        sigma_orientation=("17", "18", "19"),
        temp="20",
        time="21",
        pose_id="1",
        header=False,
        length_unit="m",
        joint_unit="rad",
    )
    text = _file(t, length="m", joint="rad", with_header=False)
    _check(parse_tracker(text, "f", by_number), t)


def test_deviation_columns_and_their_sign():
    text = "x_t,dx,q1,q2\n100,1.5,10,20\n200,-2.5,30,40\n"
    lay = TrackerLayout(joints=("q1", "q2"), position=("x_t", "x_t", "x_t"),
                        deviation=("dx", "dx", "dx"))  # fmt: skip
    with pytest.raises(InputError, match=r"f:1:1: column 'x_t' is mapped twice \(x and y\)"):
        parse_tracker(text, "f", lay)
    text = "a,b,c,da,db,dc,q1,q2\n100,0,0,1.5,0,0,10,20\n200,0,0,-2.5,0,0,30,40\n"
    lay = TrackerLayout(joints=("q1", "q2"), position=("a", "b", "c"), deviation=("da", "db", "dc"))
    for sign, want in ((1.0, [101.5, 197.5]), (-1.0, [98.5, 202.5])):
        m = parse_tracker(text, "f", layout_with(lay, deviation_sign=sign))
        np.testing.assert_allclose(m.pos[:, 0] * 1e3, want)
        assert m.meta["position"] == f"(a, b, c) + ({sign:+.0f}) * (da, db, dc)"


def test_3dof_file_options_through_the_command_line(tmp_path, capsys):
    src = tmp_path / "smr.txt"
    src.write_text("# exported by the tracker\nid;J1;J2;J3;X;Y;Z\n"
                   "a;10,5;20;30;1,25;2;3\nb;11;21;31;4;5;6,5\n")  # fmt: skip
    out = tmp_path / "m.csv"
    argv = ["import", "tracker", str(src), "--out", str(out), "--joints", "J1,J2,J3",
            "--position", "X,Y,Z", "--decimal", "comma", "--length-unit", "m",
            "--pose-id", "id", "--instrument", "AT960 + 1.5in SMR"]  # fmt: skip
    assert main(argv) == 0
    assert "2 poses, 3 joints, position only" in capsys.readouterr().out
    m = formats.read_measurements(out, 3)
    np.testing.assert_allclose(m.pos, [[1.25, 2, 3], [4, 5, 6.5]])
    np.testing.assert_allclose(np.degrees(m.q[0]), [10.5, 20, 30])
    assert m.pose_id == ("a", "b") and m.meta["instrument"] == "AT960 + 1.5in SMR"


# ------------------------------------------------------------------ one-line refusals

_SMALL = "id;J1;J2;X;Y;Z;A;B;C\np1;10;20;100;200;300;10;20;30\np2;11;21;101;201;301;11;21;31\n"
_SMALL_MAP = TrackerLayout(
    joints=("J1", "J2"), position=("X", "Y", "Z"), orientation=("A", "B", "C"), euler="ZYX"
)

_RADIANS = "id;J1;J2;X;Y;Z;A;B;C\np1;0.1;0.2;1;2;3;10;20;30\np2;1.5;0.3;1;2;3;10;20;30\n" + (
    "p3;-0.3;0.4;1;2;3;10;20;30\n"
)


def _row(text: str, line: int, col: int, value: str) -> str:
    lines = text.splitlines()
    cells = lines[line - 1].split(";")
    cells[col - 1] = value
    lines[line - 1] = ";".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("text", "changes", "pattern"),
    [
        (_row(_SMALL, 3, 4, "1O1"), {}, r"^f:3:4: column 'X' \(x\): '1O1' is not a number$"),
        (_row(_SMALL, 2, 2, ""), {}, r"^f:2:2: column 'J1' \(q1\): empty cell$"),
        (_row(_SMALL, 2, 7, "nan"), {}, r"^f:2:7: column 'A' \(angle 1\): 'nan' is not a finite"),
        (
            _row(_SMALL, 2, 4, "100,5"),
            {},
            r"^f:2:4: .*'100,5' is not a number: a decimal comma\? "
            r"give --decimal comma$",
        ),  # fmt: skip
        (
            _row(_SMALL, 2, 4, "100.5"),
            {"decimal": "comma"},
            r"^f:2:4: column 'X' \(x\): '100.5' has a decimal point, but the file is read with "
            r"decimal commas \(--decimal comma\)$",
        ),  # fmt: skip
        ("", {}, r"^f:1:1: empty file: expected a header row"),
        ("# only a comment\n\n", {}, r"^f:1:1: empty file"),
        (_SMALL.splitlines()[0] + "\n", {}, r"^f:2:1: no data rows after the header$"),
        (
            _SMALL,
            {"position": ("X", "Y", "W")},
            r"^f:1:10: missing column 'W' \(--position, z\);"
            r" the header has: id, J1",
        ),  # fmt: skip
        (
            _SMALL.replace("B;C", "B;X"),
            {},
            r"^f:1:9: column 'X' \(--position, x\) appears 2 times in the header \(columns 4, 9\)",
        ),
        (_SMALL + "p3;1;2\n", {}, r"^f:4:4: row has 3 cells, the header has 9$"),
        (
            _row(_SMALL, 2, 2, "800"),
            {"joint_unit": "rad"},
            r"^f:2:2: joint angles look like degrees \(800 is beyond ±12.6 rad\)",
        ),  # fmt: skip
        (
            _SMALL,
            {"angle_unit": "rad"},
            r"^f:3:9: orientation angles look like degrees \(31 is beyond",
        ),  # fmt: skip
        (
            _RADIANS,
            {},
            r"^f:3:2: joint angles look like radians .* give --joint-unit rad$",
        ),  # fmt: skip
        (_SMALL, {"length_unit": "m"}, r"^f:3:4: the target is 375\.8 m from the instrument"),
        (
            _SMALL.replace("X;Y", "X [ft];Y"),
            {},
            r"^f:1:4: column 'X \[ft\]' \(x\): unit 'ft' is "
            r"not supported; convert to mm, m or in$",
        ),  # fmt: skip
        (
            _SMALL.replace("X;Y", "X [m];Y"),
            {"length_unit": "mm"},
            r"^f:1:4: column 'X \[m\]' \(x\): the header says m, but the length unit is mm "
            r"\(--length-unit\)$",
        ),  # fmt: skip
        (
            _SMALL.replace("X;Y", "X [m];Y [mm]"),
            {},
            r"^f:1:5: column 'Y \[mm\]' \(y\): the header says mm, but column 'X \[m\]' says m",
        ),
        (
            _SMALL.replace("A;B", "A [mm];B"),
            {},
            r"^f:1:7: column 'A \[mm\]' \(angle 1\): unit 'mm' is not an angle unit$",
        ),
        (
            _SMALL.replace(";A;", ";T;"),
            {"temp": "T", "orientation": None, "euler": None},
            None,
        ),  # 10 and 11 °C: fine
        (
            _row(_row(_SMALL, 2, 7, "295.1"), 3, 7, "295.2").replace(";A;", ";T;"),
            {"temp": "T", "orientation": None, "euler": None},
            r"^f:2:7: temperature 295\.1 is outside \[-50, 100\] °C",
        ),  # fmt: skip
        (_row(_SMALL, 2, 1, "\x01x"), {"pose_id": "id"}, r"^f:2:1: pose id .* control character"),
        (_SMALL, {"euler": "RPY"}, r"^--euler 'RPY': not an Euler convention as scipy names it"),
        (_SMALL, {"euler": "XyZ"}, r"^--euler 'XyZ': not an Euler convention"),
        (_SMALL, {"euler": "XXY"}, r"^--euler 'XXY': not an Euler convention"),
        (_SMALL, {"euler": None}, r"^--orientation needs --euler"),
        (_SMALL, {"length_unit": "ft"}, r"^--length-unit 'ft': unknown unit; use mm, m, in$"),
        (_SMALL, {"joint_unit": "grad"}, r"^--joint-unit 'grad': unknown unit; use deg, rad$"),
        (_SMALL, {"separator": "|"}, r"^--sep '\|': unknown separator"),
        (_SMALL, {"decimal": "comma", "separator": ","}, r"^--decimal comma with --sep ','"),
        (_SMALL.replace(";", ","), {"decimal": "comma"}, r"^f:1:1: no ';' or tab in the header"),
        (
            _SMALL,
            {"orientation": None, "euler": None, "sigma_orientation": ("A", "B", "C")},
            r"^--sigma-orientation without --orientation",
        ),  # fmt: skip
        (_SMALL, {"position": ("X", "Y")}, r"^--position 'X,Y': needs 3 columns, got 2$"),
        (
            _SMALL,
            {"instrument": "AT960\nq1,q2"},
            r"^--instrument 'AT960\\nq1,q2' holds a line break",
        ),
        (
            _SMALL.replace("X;Y;Z", "X{0};Y;Z").replace("A;B;C", "dX;B;C"),
            {
                "position": ("X{0}", "Y", "Z"),
                "deviation": ("dX", "B", "C"),
                "orientation": None,
                "euler": None,
            },
            None,
        ),  # braces in a name are no format field (meta "position")
        (
            _SMALL,
            {"header": False},
            r"^--joints 'J1': without a header, columns are named by "
            r"number \(1 … 9\)$",
        ),  # fmt: skip
        (
            _row(_SMALL, 2, 2, "0"),
            {
                "sigma_position": ("J1", "J2", "X"),
                "position": ("Y", "Z", "A"),
                "joints": ("B",),
                "orientation": None,
                "euler": None,
            },
            r"^f:2:2: column 'J1' \(sx\): uncertainty 0 must be > 0$",
        ),  # fmt: skip
    ],
)
def test_refusals_are_one_line_with_file_line_column(text, changes, pattern):
    lay = replace(_SMALL_MAP, **changes)
    if pattern is None:
        parse_tracker(text, "f", lay)
        return
    with pytest.raises(InputError) as exc:
        parse_tracker(text, "f", lay)
    msg = str(exc.value)
    assert "\n" not in msg
    assert re.search(pattern, msg), msg


def test_a_wam_file_without_a_column_names_it(tmp_path):
    p = tmp_path / "wam.csv"
    p.write_text("x_t,y_t,z_t\n1,2,3\n")
    with pytest.raises(
        InputError, match=r"wam\.csv:1:4: missing column 'joint_1' \(--joints, q1\)"
    ):
        formats.read_wam_csv(p, 1.0)


def test_quaternion_round_trip_of_the_written_file(tmp_path):
    """The written quaternion is the rotation to 1e-12 (the CSV v1 reader's own check)."""
    t = _truth(6)
    m = parse_tracker(_file(t), "f", _MAP)
    out = tmp_path / "m.csv"
    formats.write_measurements(out, m)
    back = formats.read_measurements(out, 6)
    assert np.abs(back.R - t["rot"]).max() < 1e-12
    rows = list(csv.DictReader(ln for ln in out.open() if not ln.startswith("#")))
    quat = np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")] for r in rows])
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-15)
    assert np.abs(quat_to_R(quat) - t["rot"]).max() < 1e-12


def test_joint_temperatures_and_torques_are_mapped_when_the_file_has_them(tmp_path, capsys):
    """A tracker export with the controller's per-joint columns: named temp_j1 … / tau_j1 …
    they are mapped without options; under other names by --joint-temps / --joint-torques."""
    t = _truth(7)
    n = len(t["q_deg"])
    temps = 30.0 + np.arange(n * 6).reshape(n, 6) * 0.01
    taus = np.linspace(-40.0, 40.0, n * 6).reshape(n, 6)
    base = _file(t).splitlines()

    def with_cols(names_t: list[str], names_u: list[str]) -> str:
        lines = [",".join([base[0], *names_t, *names_u])]
        for r, a, b in zip(base[1:], temps, taus, strict=True):
            lines.append(",".join([r, *map(repr, a.tolist()), *map(repr, b.tolist())]))
        return "\n".join(lines) + "\n"

    named = with_cols([f"temp_j{i} [°C]" for i in range(1, 7)], [f"tau_j{i}" for i in range(1, 7)])
    m = parse_tracker(named, "f.csv", layout_with(_MAP, separator=","))
    np.testing.assert_allclose(m.joint_temp, temps)
    np.testing.assert_allclose(m.joint_torque, taus)
    other = with_cols([f"T{i}" for i in range(1, 7)], [f"M{i}" for i in range(1, 7)])
    m = parse_tracker(other, "f.csv", layout_with(_MAP, separator=","))
    assert m.joint_temp is None and m.joint_torque is None  # not named, not asked for
    src, out = tmp_path / "x.csv", tmp_path / "m.csv"
    src.write_text(other)
    argv = ["import", "tracker", str(src), "--out", str(out), "--sep", ","]
    argv += ["--joints", ",".join(_MAP.joints), "--position", "X,Y,Z", "--orientation", "A,B,C"]
    argv += ["--euler", "XYZ", "--joint-temps", ",".join(f"T{i}" for i in range(1, 7))]
    argv += ["--joint-torques", ",".join(f"M{i}" for i in range(1, 7))]
    assert main(argv) == 0
    assert "joint temperatures, joint torques" in capsys.readouterr().out
    back = formats.read_measurements(out, 6)
    np.testing.assert_allclose(back.joint_temp, temps)
    np.testing.assert_allclose(back.joint_torque, taus)
    with pytest.raises(InputError, match=r"--joint-temps 'T1,T2': needs one column per joint"):
        parse_tracker(other, "f.csv", layout_with(_MAP, separator=",", joint_temps=("T1", "T2")))
    hot = other.replace(repr(float(temps[0, 1])), "250.0", 1)
    with pytest.raises(InputError, match=r"f\.csv:2:\d+: joint 2 temperature: 250 °C is outside"):
        parse_tracker(
            hot,
            "f.csv",
            layout_with(_MAP, separator=",", joint_temps=tuple(f"T{i}" for i in range(1, 7))),
        )
