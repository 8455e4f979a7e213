"""How every door fits, reports and judges: the options and their defaults, in one place.

``identify fit``, the TUI's Results screen, ``reprocess`` and the demo fit with
:class:`FitOptions`; ``report``, the TUI and ``reprocess`` report with :class:`ReportOptions`.
A door sets what its user chose and leaves the rest to these defaults, so the same data give
the same model, figures and verdict whichever door they came through.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ...identify.assess import MAX_ORDER, WORKSPACE_SAMPLES
from ...identify.errormodel import ErrorModelSpec
from ...identify.fit import ParameterPrior
from ...identify.linearize import InstrumentNoise
from ..reporting.verdict import Spec


@dataclass(frozen=True)
class FitOptions:
    """What a fit assumes and searches (SI).

    Attributes
    ----------
    effects : tuple of str
        Effect names added to the paper's Chebyshev model (CONTRACTS.md).
    max_order : int
        Cap of every series' order in the BIC search.
    noise : InstrumentNoise
        Instrument uncertainties where the data have no per-row columns (0.03 mm, 0.1 mrad).
    prior : ParameterPrior
    spec : ErrorModelSpec or None
        Fixed orders and ranges instead of the search (``reprocess --orders keep``).
    margin : float or None
        BIC drop a raise must reach (None: the search's default).
    auto_rescale : bool
        Rerun once with the suspected uncertainty raised if the χ² check fails.
    workspace_samples : int
        Joint commands of the workspace error map.
    """

    effects: tuple[str, ...] = ()
    max_order: int = MAX_ORDER
    noise: InstrumentNoise = field(default_factory=InstrumentNoise)
    prior: ParameterPrior = field(default_factory=ParameterPrior)
    spec: ErrorModelSpec | None = None
    margin: float | None = None
    auto_rescale: bool = False
    workspace_samples: int = WORKSPACE_SAMPLES


@dataclass(frozen=True)
class ReportOptions:
    """What a report judges with.

    Attributes
    ----------
    accuracy_spec : Spec or None
        The accuracy spec this report judges against instead of the run's own (a command's
        ``--threshold-mm``; None: the run's, :func:`~..reporting.verdict.spec_of_run`).
    diagnose_if_missing : bool
        Run the diagnosis when the run folder has no ``diagnosis.json``.
    workspace_samples : int
        Joint commands of the report's workspace error map.
    """

    accuracy_spec: Spec | None = None
    diagnose_if_missing: bool = True
    workspace_samples: int = WORKSPACE_SAMPLES
