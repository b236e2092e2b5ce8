"""A diagnosis's time budget: when its optional searches stop, and what they left untried.

The stages a verdict needs (the nominal model, the evidence, the baseline) always run; the
searches that refine it (the other structures, each further step of the selection, the check
against rival effects, the detection limits) start only while the budget lasts, and each one
a spent budget skips is recorded, for the report to say what was not tried.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from exo_has_sim.errors import DiagnosisError


@dataclass
class TimeBudget:
    """Wall-clock seconds a diagnosis may take, counted from its creation.

    Attributes
    ----------
    seconds : float
        The budget [s]; infinite for none.
    started : float
        :func:`time.perf_counter` at its creation [s].
    untried : list[str]
        What the spent budget skipped, in order.

    """

    seconds: float = math.inf
    started: float = field(default_factory=time.perf_counter)
    untried: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.seconds > 0.0:
            msg = f'a time budget must be positive seconds, got {self.seconds!r}'
            raise DiagnosisError(msg)

    @property
    def spent(self) -> bool:
        """Whether the budget has run out."""
        return time.perf_counter() - self.started >= self.seconds

    def allows(self, what: str) -> bool:
        """Say whether a search may start; if not, record ``what`` as untried."""
        if not self.spent:
            return True
        self.untried.append(what)
        return False
