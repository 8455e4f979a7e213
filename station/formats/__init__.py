"""Files of the identification, one module per format.

- :mod:`.measurements`: measurement CSV v1 (CONTRACTS.md), and the meaning checks before a fit;
- :mod:`.model`: model.json (``quickhealth.model/1``);
- :mod:`.report`: report.json (``quickhealth.report/2``): content, schema, writer, reader, checker;
- :mod:`.residuals`: residuals.csv (measured minus model per pose);
- :mod:`.robot`: robot descriptions (``--robot``: built-in name, DH table TOML, URDF) and
  the controller calibration (``--calibration``: the UR ROS driver's kinematics YAML);
- :mod:`.urscript`: URScript programs (joint targets for ``predict``, ``compensate``);
- :mod:`.tracker`: laser-tracker exports of any column layout (``import tracker``, presets);
- :mod:`.wam`: the Barrett WAM laser-tracker data set (the tracker importer's ``wam`` preset);
- :mod:`.journal`: the run journal's records (typed in SI, stored in mm and degrees);
- :mod:`.vision`: the 7D camera's files (images, CAL.json, target descriptions; OpenCV, so
  imported by name, not re-exported here);
- :mod:`.common`: what they share: the read limits and the one atomic write (``fsio``).

Every unit conversion between the file boundary (mm, degrees) and the library (m, rad)
happens here, once.  Every bad input raises :class:`InputError` with one line
``file:line:column: what`` (line and column 1-based; column = the CSV column).
Everything is re-exported here: ``from quickhealth.station.formats import read_model``.
"""

from __future__ import annotations

from .common import (
    MAX_BYTES,
    MAX_CELL_CHARS,
    MAX_FIT_ROWS,
    MAX_JSON_DEPTH,
    MAX_ROWS,
    MIN_DISTINCT_POSES,
    MIN_JOINT_SPAN_DEG,
    MiB,
    csv_cell,
    csv_text,
    excerpt,
    finite_float,
    load_json_limited,
    one_line,
    read_text_limited,
    write_text_atomic,
)
from .measurements import (
    OPTIONAL_COLUMNS,
    check_fit_rows,
    check_joint_limits,
    check_poses_for_fit,
    format_measurements,
    parse_measurements,
    read_measurements,
    write_measurements,
)
from .model import (
    MODEL_SCHEMA,
    check_model,
    model_from_json,
    model_to_json,
    read_model,
    valid_model,
    write_model,
)
from .report import (
    REPORT_FIGURES,
    REPORT_NUMBERS,
    REPORT_SCHEMA,
    REPORT_SCHEMAS_READ,
    REQUIRED,
    WORKSPACE_KEYS,
    check_report,
    read_report,
    report_of,
    trend_to_json,
    with_sections,
    write_report,
    write_report_json,
)
from .residuals import residual_table
from .robot import (
    BUILTIN_ROBOTS,
    calibrated_robot,
    check_robot,
    load_robot,
    read_dh_toml,
    read_ur_calibration,
    read_urdf,
    robot_from_json,
    robot_spec_mm,
    robot_to_json,
)
from .tracker import PRESETS as TRACKER_PRESETS
from .tracker import TrackerLayout, parse_tracker, read_tracker
from .urscript import read_urscript, read_urscript_joints
from .wam import read_wam_csv

__all__ = [
    "BUILTIN_ROBOTS",
    "MAX_BYTES",
    "MAX_CELL_CHARS",
    "MAX_FIT_ROWS",
    "MAX_JSON_DEPTH",
    "MAX_ROWS",
    "MIN_DISTINCT_POSES",
    "MIN_JOINT_SPAN_DEG",
    "MODEL_SCHEMA",
    "OPTIONAL_COLUMNS",
    "REPORT_FIGURES",
    "REPORT_NUMBERS",
    "REPORT_SCHEMA",
    "REPORT_SCHEMAS_READ",
    "REQUIRED",
    "TRACKER_PRESETS",
    "WORKSPACE_KEYS",
    "MiB",
    "TrackerLayout",
    "calibrated_robot",
    "check_fit_rows",
    "check_joint_limits",
    "check_model",
    "check_poses_for_fit",
    "check_report",
    "check_robot",
    "csv_cell",
    "csv_text",
    "excerpt",
    "finite_float",
    "format_measurements",
    "load_json_limited",
    "load_robot",
    "robot_spec_mm",
    "model_from_json",
    "model_to_json",
    "one_line",
    "parse_measurements",
    "parse_tracker",
    "read_dh_toml",
    "read_ur_calibration",
    "read_measurements",
    "read_model",
    "read_report",
    "read_tracker",
    "read_text_limited",
    "read_urdf",
    "read_urscript",
    "read_urscript_joints",
    "read_wam_csv",
    "report_of",
    "residual_table",
    "robot_from_json",
    "robot_to_json",
    "trend_to_json",
    "valid_model",
    "with_sections",
    "write_measurements",
    "write_model",
    "write_report",
    "write_report_json",
    "write_text_atomic",
]
