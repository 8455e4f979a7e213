"""Bounds of the command line's numeric options: one argparse type per kind of quantity.

Every numeric option names the quantity it takes (``type=SEED``, ``type=SIGMA_POS_MM``): the
type parses the text, refuses what is not a finite number of the right kind and anything
outside the quantity's range, and argparse turns the refusal into one line and exit 2
(``quickhealth plan: error: argument --seed: -1 is not a seed (an integer in 0..4294967295)``).
A bound is where a value stops meaning anything for a real station (a noise of 1e-300 mm, a
plan of 100 000 poses that no cell runs in a shift, a negative BIC margin), not a tuning
knob; the table is docs/identify.md's "Limits".

SYNOPSIS::

    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--sigma-pos-mm", type=SIGMA_POS_MM, default=0.03)
"""

from __future__ import annotations

import argparse
import math


class Bounded:
    """An argparse type: a number (int or float) in ``[lo, hi]`` (``lo`` excluded with
    ``lo_open``).  Its name is what argparse prints for a value it refuses."""

    def __init__(
        self, kind: type, lo: float, hi: float, what: str, *, lo_open: bool = False
    ) -> None:
        self.kind, self.lo, self.hi, self.what, self.lo_open = kind, lo, hi, what, lo_open
        self.__name__ = what  # argparse's "invalid <name> value" for other failures

    def describe(self) -> str:
        """The accepted range in words, e.g. ``an integer in 1..1000``."""
        if self.kind is int:
            return f"an integer in {self.lo:d}..{self.hi:d}"
        left = "(" if self.lo_open else "["
        return f"a number in {left}{self.lo:g}, {self.hi:g}]"

    def __call__(self, text: str) -> int | float:
        s = str(text).strip()
        try:
            v: int | float = int(s) if self.kind is int else float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{s[:40]!r} is not {self.what} ({self.describe()})"
            ) from None
        ok = math.isfinite(v) and (self.lo < v if self.lo_open else self.lo <= v) and v <= self.hi
        if not ok:
            raise argparse.ArgumentTypeError(f"{s[:40]} is not {self.what} ({self.describe()})")
        return v

    def __repr__(self) -> str:  # shown by argparse in some messages
        return self.what


# -- counts
PLAN_POSES = Bounded(int, 1, 1000, "a number of poses")  # plan --n: ~1 min at 1000
TWIN_POSES = Bounded(int, 1, 20_000, "a number of poses")  # the fit's row limit
HELDOUT_POSES = Bounded(int, 0, 20_000, "a number of poses")
SEED = Bounded(int, 0, 2**32 - 1, "a seed")
WORKERS = Bounded(int, 1, 256, "a number of worker processes")
ORDER = Bounded(int, 0, 40, "a Chebyshev order")
FOLDS = Bounded(int, 2, 100, "a number of folds")
TOP = Bounded(int, 1, 1000, "a number of candidates")
HARMONIC = Bounded(int, 1, 1000, "a harmonic")
SAMPLES = Bounded(int, 100, 1_000_000, "a number of workspace samples")

# -- instrument noise: from an interferometer (0.1 µm) to a hand-held tape (100 mm)
SIGMA_POS_MM = Bounded(float, 1e-4, 100.0, "a position uncertainty in mm")
SIGMA_ROT_DEG = Bounded(float, 1e-6, 10.0, "an orientation uncertainty in deg")
SIGMA_ROT_MRAD = Bounded(float, 1e-5, 100.0, "an orientation uncertainty in mrad")
SIGMA_Q_DEG = Bounded(float, 0.0, 10.0, "an encoder uncertainty in deg")

# -- decisions
MARGIN = Bounded(float, 0.0, 1e4, "a BIC margin")
PROBABILITY = Bounded(float, 0.0, 1.0, "a probability", lo_open=True)
LENGTH_MM = Bounded(float, 0.0, 1e4, "a length in mm", lo_open=True)
CHANGE_MM = Bounded(float, 0.0, 1e3, "a length in mm")
CHANGE_MRAD = Bounded(float, 0.0, 1e3, "an angle in mrad")
TIMEOUT_S = Bounded(float, 0.0, 3600.0, "a time in s", lo_open=True)

# -- the digital twin's data (0: noise-free synthetic data)
NOISE_POS_MM = Bounded(float, 0.0, 100.0, "a position noise in mm")
NOISE_ROT_MRAD = Bounded(float, 0.0, 100.0, "an orientation noise in mrad")
DURATION_S = Bounded(float, 0.0, 1e7, "a duration in s", lo_open=True)
TEMP_RISE_K = Bounded(float, -50.0, 50.0, "a temperature change in K")
PAYLOAD_KG = Bounded(float, 0.0, 100.0, "a payload in kg")

# -- the quick check
FALSE_ALARM = Bounded(float, 1e-6, 0.2, "a false-alarm probability")
POWER = Bounded(float, 0.5, 0.999999, "a power", lo_open=True)
DETECT_MM = Bounded(float, 1e-4, 10.0, "a TCP change in mm")
