import json
from pathlib import Path

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.transforms import make_T
from quickhealth.vision.boards import (
    BoardKind,
    TargetDescription,
    pan_transform,
    parse_board_spec,
    reference_target,
)

DATA = Path(__file__).resolve().parents[2] / "vision" / "data"


def test_board_specs():
    b = parse_board_spec("chessboard:9x6:25")
    assert b.kind is BoardKind.CHESSBOARD and b.n_corners == 54 and b.square == 0.025
    assert np.allclose(b.object_points()[10], [0.025, 0.025, 0])
    c = parse_board_spec("charuco:7x5:30:21:DICT_4X4_50")
    assert c.kind is BoardKind.CHARUCO and c.n_corners == 24 and c.marker == pytest.approx(0.021)
    assert np.allclose(c.object_points()[0], [0.03, 0.03, 0])
    for bad in (
        "chessboard:9x6",
        "charuco:7x5:30:40:DICT_4X4_50",
        "checker:9x6:20",
        "charuco:7x5:30:21:DICT_FOO",
    ):
        with pytest.raises(InputError):
            parse_board_spec(bad)


def test_target_file_round_trip_and_grid_shorthand():
    t = reference_target()
    d = json.loads(json.dumps(t.to_dict()))
    t2 = TargetDescription.from_dict(d)
    assert (
        np.array_equal(t2.ids, t.ids) and np.allclose(t2.corners, t.corners) and t2.n_corners == 192
    )
    g = TargetDescription.from_dict(
        {"format": "quickhealth-target", "version": 1, "dictionary": "DICT_4X4_50",
         "grid": {"cols": 8, "rows": 6, "marker_mm": 24, "pitch_mm": 32}}
    )  # fmt: skip
    assert np.allclose(g.corners, t.corners)
    # the shipped files are the reference design
    assert (
        TargetDescription.from_dict(
            json.loads((DATA / "reference_target.json").read_text())
        ).n_corners
        == 192
    )
    rig = json.loads((DATA / "reference_rig.json").read_text())
    assert rig["baseline_mm"] == pytest.approx(800.0) and rig["cameras"][0]["image_size"] == [
        4000,
        3000,
    ]


@pytest.mark.parametrize(
    ("doc", "needle"),
    [
        ({"format": "other", "version": 1}, "not a quickhealth-target"),
        ({"format": "quickhealth-target", "version": 1, "dictionary": "DICT_4X4_50"}, "no markers"),
        ({"format": "quickhealth-target", "version": 1, "dictionary": "DICT_4X4_50",
          "markers": [{"id": 1, "corners_mm": [[0, 0, 0]]}]}, "4 finite"),
        ({"format": "quickhealth-target", "version": 1, "dictionary": "DICT_4X4_50",
          "markers": [{"id": 99, "corners_mm": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]}, "outside DICT_4X4_50"),
    ],
)  # fmt: skip
def test_bad_target_files(doc, needle):
    with pytest.raises(InputError, match=needle):
        TargetDescription.from_dict(doc, where="t.json")


def test_pan_turns_about_the_axis():
    t = reference_target()
    T = pan_transform(t, np.radians(90))
    assert np.allclose(T @ [0, 1, 0, 1], [0, 1, 0, 1])  # points on the axis stay
    assert np.allclose((T @ [1, 0, 0, 1])[:3], [0, 0, -1], atol=1e-12)
    assert np.allclose(pan_transform(t, 0.0), make_T(np.eye(3), np.zeros(3)))
