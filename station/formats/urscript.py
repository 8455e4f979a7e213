"""URScript programs: the one reader of joint targets for ``predict`` and ``compensate``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.urscript import joint_targets
from .common import findings, read_text_limited

F = NDArray[np.float64]


def read_urscript(path: str | os.PathLike[str], n_joints: int) -> tuple[str, Any]:
    """A URScript program's text and its joint targets (:mod:`quickhealth.identify.urscript`).

    The one reader of programs for ``predict`` and ``compensate``.  Every move whose target
    cannot be read (a variable, a pose literal ``p[...]``, an expression, a wrong length) is
    refused, one line per target (``file:line:column: what``): nothing is guessed.

    Raises
    ------
    InputError
        Missing or binary file, a program that does not tokenize, unreadable targets, no
        target at all.
    """

    p = Path(path)
    text = read_text_limited(p, "program")
    if "\x00" in text:
        raise InputError(f"{p}: not a URScript program (binary content)")
    try:
        t = joint_targets(text, n_joints)
    except InputError as exc:
        raise InputError(f"{p}:{exc}") from None
    if t.unreadable:
        raise findings([f"{p}:{line}:{col}: {cmd} {why}" for line, col, cmd, why in t.unreadable])
    if not len(t.q):
        raise InputError(f"{p}:1:1: no movej/movel with a joint target found")
    return text, t


def read_urscript_joints(path: str | os.PathLike[str], n_joints: int) -> tuple[F, list[int]]:
    """Joint targets (rad, shape (n, n_joints)) and their 1-based lines (:func:`read_urscript`)."""
    _, t = read_urscript(path, n_joints)
    return t.q, list(t.lines)
