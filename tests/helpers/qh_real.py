"""The real data sets the way a user meets them, split for held-out checks.

Imported as ``qh_real`` by the tests (pytest puts ``tests/helpers`` on ``sys.path``) and by
``benchmarks/real_data.py``.

**The shared UR10 split** (documented in docs/identify.md): the series' 1,495 rows reach 757
goal poses, 738 of them twice (two joint solutions, or the same one measured again).  Rows of
one goal stay together, so a held-out row never has its twin in the training set: the goals
are numbered in the order they first appear, and every fifth goal (numbers 4, 9, 14, …) is
held out: 295 rows held out, 1,200 for fitting.  Nothing is fitted, selected or tuned on the
held-out rows.

**Two sessions of the shared UR10** (the monitoring checks: trend, ``check --replay``): the
same robot measured twice on different poses.  Only the fitting part of the split above is
used (the held-out rows stay untouched): its goals, numbered in order of first appearance
among the fitting rows, go to session A when even and to session B when odd (rows of one goal
stay together): 600 rows each, spread alike over the workspace.

**The WAM**: grid.csv (216 poses) for fitting, random.csv (20 poses) held out, as published.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from quickhealth.identify.measurements import Measurements
from quickhealth.station import formats
from quickhealth.station.formats.tracker import PRESETS, read_tracker

ROOT = Path(__file__).resolve().parents[2]
UR10_FILE = ROOT / "fixtures" / "ipa-ur10" / "measurements_joint_configurations.csv"
UR10_ROBOT = ROOT / "fixtures" / "robots" / "ur10.toml"
WAM_DIR = ROOT / "fixtures" / "wam"
WAM_ROBOT = ROOT / "fixtures" / "robots" / "wam.toml"
SHARED_REAL = ROOT.parent / "shared" / "real"
HELD_EVERY = 5  # every fifth goal is held out


def ur10_goal_groups(path: Path = UR10_FILE) -> np.ndarray:
    """Goal number of every row (goals numbered in order of first appearance), shape (n,)."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f, delimiter=";"))
    head = rows[0]
    cols = [
        head.index(c) for c in ("Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw")
    ]
    goals = np.array([[float(r[c].replace(",", ".")) for c in cols] for r in rows[1:]])
    _, first, inv = np.unique(np.round(goals, 5), axis=0, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))  # goal number by first appearance
    return rank[inv.ravel()]


def ur10_split(path: Path = UR10_FILE) -> tuple[Measurements, Measurements]:
    """The documented split of the shared UR10 series: (fit, held out), file order kept."""
    meas = read_tracker(path, PRESETS["ipa-ur10"])
    held = ur10_goal_groups(path) % HELD_EVERY == HELD_EVERY - 1
    return meas.subset(np.flatnonzero(~held)), meas.subset(np.flatnonzero(held))


def ur10_sessions(path: Path = UR10_FILE) -> tuple[Measurements, Measurements]:
    """The two documented sessions of the shared UR10 (module doc), file order kept."""
    meas = read_tracker(path, PRESETS["ipa-ur10"])
    goals = ur10_goal_groups(path)
    fit = goals % HELD_EVERY != HELD_EVERY - 1
    rank = {g: i for i, g in enumerate(dict.fromkeys(goals[fit]))}
    side = np.array([rank[g] % 2 if f else -1 for g, f in zip(goals, fit, strict=True)])
    return meas.subset(np.flatnonzero(side == 0)), meas.subset(np.flatnonzero(side == 1))


def write_ur10_split(folder: Path, path: Path = UR10_FILE) -> tuple[Path, Path]:
    """The split as two CSV v1 files in ``folder``: ``train.csv``, ``heldout.csv``."""
    folder.mkdir(parents=True, exist_ok=True)
    train, held = ur10_split(path)
    out = folder / "train.csv", folder / "heldout.csv"
    formats.write_measurements(out[0], train)
    formats.write_measurements(out[1], held)
    return out
