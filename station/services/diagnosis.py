"""Which physical effect does a fitted model miss?  The diagnosis of a model on data.

:func:`diagnose_model` is ``quickhealth diagnose`` without its files: the residual tests of
every candidate effect (:func:`quickhealth.identify.diagnose.diagnose`) against the model,
the candidates named by the caller checked first.  The report runs it when a run folder has
no diagnosis.json; the demo and the command write its document (CONTRACTS.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ...identify.diagnose import Diagnosis, LoopState, diagnose, state_from_fitted
from ...identify.effects import NotIdentifiable, parse_effect
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.sanity import check_describes
from ..formats.common import write_text_atomic

#: The family-wise false-alarm rate and the highest cyclic harmonic tested by default.
ALPHA = 0.01
MAX_HARMONIC = 30


@dataclass(frozen=True, eq=False)
class Diagnosed:
    """The diagnosis and the model state it tested (for the figures of its candidates)."""

    state: LoopState
    diagnosis: Diagnosis


def diagnose_model(
    fitted: FittedModel,
    meas: Measurements,
    *,
    candidates: Sequence[str] | None = None,
    alpha: float = ALPHA,
    max_harmonic: int = MAX_HARMONIC,
    name: str = "the data",
    progress: Callable[[str], None] | None = None,
    advance: Callable[[int, int, str], None] | None = None,
) -> Diagnosed:
    """The diagnosis of ``fitted`` on ``meas`` (the fitted data or new data of the robot).

    ``progress`` and ``advance`` receive the stages and the candidates tested (a command's
    progress bar); ``name`` names the data in errors.

    Raises
    ------
    InputError
        An unknown candidate effect name; data the model does not describe
        (:func:`~quickhealth.identify.sanity.check_describes`: another robot or set-up).
    """
    cands = None if candidates is None else list(candidates)
    for c in cands or ():
        try:
            parse_effect(c, fitted.robot)  # InputError for unknown names
        except NotIdentifiable:
            pass  # explained, never fitted: the diagnosis says why
    check_describes(fitted, meas, name)
    state = state_from_fitted(fitted)
    diag = diagnose(
        state,
        meas,
        candidates=cands,
        alpha=alpha,
        max_harmonic=max_harmonic,
        progress=progress,
        advance=advance,
    )
    return Diagnosed(state, diag)


def write_diagnosis(path: Path, diagnosis: Diagnosis) -> None:
    """The contract's JSON document of a diagnosis (``diagnose --json``), atomically."""
    write_text_atomic(path, json.dumps(diagnosis.to_dict(), indent=1) + "\n")
