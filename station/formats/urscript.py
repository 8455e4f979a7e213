"""URScript programs: the one reader of joint targets for ``predict`` and ``compensate``."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.urscript import joint_targets
from .common import findings, read_text_limited

F = NDArray[np.float64]


def read_urscript(
    path: str | os.PathLike[str], n_joints: int, leave: Sequence[str] | None = None
) -> tuple[str, Any]:
    """A URScript program's text and its joint targets (:mod:`quickhealth.identify.urscript`).

    The one reader of programs for ``predict`` and ``compensate``.  Every motion whose
    target cannot be read (a variable, a pose literal ``p[...]``, an expression, a wrong
    length) or that has none (``speedl``, ``force_mode`` …) is refused, one line per motion
    naming it (``file:line:column: what``): nothing is guessed or skipped; except the
    commands named in ``leave`` (``compensate --leave``; None: the caller has no such
    option), which stay as written and come back in the targets' ``left``.

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
    refused = [u for u in t.unreadable if leave is None or u[2] not in leave]
    if refused:
        raise findings(
            [
                f"{p}:{line}:{col}: {cmd} {why}"
                + ("" if leave is None else f" (or --leave {cmd} to keep it as written)")
                for line, col, cmd, why in refused
            ]
        )
    t = replace(t, unreadable=(), left=tuple(u for u in t.unreadable if u[2] in (leave or ())))
    if not len(t.q):
        raise InputError(f"{p}:1:1: no movej/movel with a joint target found")
    return text, t


def read_urscript_joints(path: str | os.PathLike[str], n_joints: int) -> tuple[F, list[int]]:
    """Joint targets (rad, shape (n, n_joints)) and their 1-based lines (:func:`read_urscript`)."""
    _, t = read_urscript(path, n_joints)
    return t.q, list(t.lines)
