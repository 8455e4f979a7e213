"""Cell files: the reference cell and one-line refusals of bad files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.station.planning.cell import load_cell, parse_cell

REF = Path(__file__).parents[2] / "station" / "data" / "reference_cell.toml"


def test_reference_cell_matches_the_paper_and_vision_design():
    cell = load_cell("reference")
    assert cell.robot.name == "ur5"
    assert cell.baseline == pytest.approx(0.8)
    h, v = cell.camera.fov_deg
    assert h == pytest.approx(43.6, abs=0.1) and v == pytest.approx(33.4, abs=0.1)
    mid = (cell.T_world_cam_left[:3, 3] + cell.T_world_cam_right[:3, 3]) / 2
    assert 1.8 < np.linalg.norm(mid[:2] - cell.T_world_base[:2, 3]) < 2.2  # about 2 m in front
    # camera frames: z = optical axis towards the robot, y down
    for T in (cell.T_world_cam_left, cell.T_world_cam_right):
        assert T[0, 2] < -0.9 and T[2, 1] < -0.9
        assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3))
    assert cell.T_base_cam_left.shape == (4, 4)
    assert cell.T_flange_target[2, 3] == pytest.approx(0.1)
    assert math.degrees(cell.robot.q_max[0]) == pytest.approx(180)
    assert load_cell(REF).sha256 == cell.sha256


def _text() -> str:
    return REF.read_text()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda s: s.replace('model = "ur5"', 'model = "kuka"'),
            r"robot\.model: unknown robot 'kuka'",
        ),
        (
            lambda s: s.replace("fx_px = 5000", 'fx_px = "5000"'),
            r"camera\.fx_px: expected a number",
        ),
        (lambda s: s.replace("fx_px = 5000", "fx_px = nan"), r"camera\.fx_px: not a finite number"),
        (
            lambda s: s.replace("min_mm = [-350, -700, 60]", "min_mm = [-350, -700, -60]"),
            r"workspace\.min_mm: .*not above the table",
        ),
        (
            lambda s: s.replace("settle_s = 0.5", "settle_s = 0.5\nsetle_s = 1"),
            r"motion\.setle_s: unknown key",
        ),
        (
            lambda s: s.replace("look_at_mm = [200, 0, 350]", "look_at_mm = [200, 0]", 1),
            r"camera\.left\.look_at_mm: expected a list of 3",
        ),
        (
            lambda s: s.replace('shape = "box"', 'shape = "sphere"', 1),
            r"obstacle\[0\]\.shape: expected 'box' or 'cylinder'",
        ),
        (
            lambda s: s.replace(
                "q_max_deg = [180, 180, 180, 180, 180, 180]",
                "q_max_deg = [400, 180, 180, 180, 180, 180]",
            ),
            r"robot\.q_min_deg: planning limits",
        ),
        (lambda s: s.replace("fy_px = 5000\n", ""), r"camera\.fy_px: missing"),
        (
            lambda s: s.replace('name = "reference"', 'name = "ref; rm -rf /"'),
            r"name: .*not allowed",
        ),
    ],
)
def test_bad_cell_files_give_one_line_errors(edit, message):
    with pytest.raises(InputError, match=message) as e:
        parse_cell(edit(_text()).encode(), "cell.toml")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("cell.toml")


def test_yaml_tag_and_non_toml_payloads_are_refused():
    yaml = b"robot: !!python/object/apply:os.system ['echo pwned']\n"
    with pytest.raises(InputError, match=r"cell\.toml:1: YAML object tag") as e:
        parse_cell(yaml, "cell.toml")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="YAML cell files are not accepted"):
        parse_cell(_text().encode(), "cell.yaml")
    import pickle

    for payload in (
        pickle.dumps({"a": 1}),
        b'{"schema": "quickhealth.cell/1"}',
        b"\x00\x01\x02garbage",
    ):
        with pytest.raises(InputError, match="not a TOML cell file") as e:
            parse_cell(payload, "cell.toml")
        assert "\n" not in str(e.value)


def test_missing_file_and_unknown_builtin():
    with pytest.raises(InputError, match="no such cell file"):
        load_cell("no-such-cell")
