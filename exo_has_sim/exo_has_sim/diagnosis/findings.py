"""The judgement of a model's structure: its findings, the other structures fitted, the verdict.

Each piece of evidence on the structure is a :class:`Finding`, gating the verdict or reported
beside it; another structure of the plant fitted to the record is an :class:`Alternative`; a
:class:`Judgement` holds them both and says the verdict (how they are gathered:
:mod:`~exo_has_sim.diagnosis.structure`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

#: An alternative whose normalised error is within this factor of the best's is reported as
#: fitting as well (:attr:`Judgement.alike`): one record's validated errors differ by more
#: between fits that ended in other local minima (1.8 times, the first plant's 5005 from its
#: position, fitted with two ways of taking the Jacobian).
ALIKE = 1.25


@dataclass(frozen=True)
class Finding:
    """One piece of evidence on the model's structure.

    Attributes
    ----------
    check : str
        Identifier (``stroke``, ``runaway``, ``direction_gain``, ``rod_pressure``,
        ``motor_shortfall``, ``resisting_load``, ``fit:<output>``, ``bound:<parameter>``,
        ``interval:<parameter>``, ``far:<parameter>``).
    passed : bool
        Whether the structure passes it.
    value : float
        The statistic.
    threshold : float
        Where it fails.
    text : str
        What it says, in a sentence.
    gating : bool
        Whether it decides the verdict (else it is reported only).

    """

    check: str
    passed: bool
    value: float
    threshold: float
    text: str
    gating: bool = True

    def to_json(self) -> dict[str, Any]:
        """Return the finding as the JSON document carries it."""
        return {'check': self.check, 'passed': self.passed, 'value': _finite(self.value),
                'threshold': _finite(self.threshold), 'text': self.text,
                'gating': self.gating}


@dataclass(frozen=True)
class Alternative:
    """Another structure of the plant, fitted to the record.

    Attributes
    ----------
    name : str
        Identifier (``circuit=switched``, ``motor_speed_input``, or both).
    description : str
        What it is.
    fits : dict[str, float]
        Validated fit [%] of each of its outputs.
    error : float
        Geometric mean over the outputs it shares with the original of ``1 - fit / 100``,
        the normalised error it ranks by.
    parameters : dict[str, float]
        Its fitted baseline parameters.
    findings : tuple[Finding, ...]
        Its own judgement.

    """

    name: str
    description: str
    fits: dict[str, float]
    error: float
    parameters: dict[str, float]
    findings: tuple[Finding, ...] = ()

    @property
    def described(self) -> bool:
        """Whether it passes every gating finding of its own."""
        return all(f.passed for f in self.findings if f.gating)

    def to_json(self) -> dict[str, Any]:
        """Return the alternative as the JSON document carries it."""
        return {'name': self.name, 'description': self.description,
                'fits': {k: _finite(v) for k, v in self.fits.items()},
                'error': _finite(self.error), 'parameters': dict(self.parameters),
                'described': self.described,
                'findings': [f.to_json() for f in self.findings if not f.passed]}


@dataclass(frozen=True)
class Judgement:
    """The structure's judgement on one record.

    Attributes
    ----------
    findings : tuple[Finding, ...]
        Every finding, gating or not.
    alternatives : tuple[Alternative, ...]
        Other structures fitted (best first), when the record failed.

    """

    findings: tuple[Finding, ...]
    alternatives: tuple[Alternative, ...] = field(default=())

    @property
    def described(self) -> bool:
        """Whether the structure passes every gating finding."""
        return all(f.passed for f in self.findings if f.gating)

    @property
    def failed(self) -> list[Finding]:
        """The gating findings the structure fails."""
        return [f for f in self.findings if f.gating and not f.passed]

    @property
    def notes(self) -> list[Finding]:
        """The findings reported only, that the structure fails."""
        return [f for f in self.findings if not f.gating and not f.passed]

    @property
    def suggestion(self) -> Alternative | None:
        """The best alternative that describes the record, if any."""
        return next((a for a in self.alternatives if a.described), None)

    @property
    def alike(self) -> list[Alternative]:
        """The other alternatives that describe the record within :data:`ALIKE` of the best.

        A pump that feeds the rod side to retract does so in a closed circuit and in a
        switched one alike while the rod side carries the load: such records cannot tell
        them apart, and the verdict says so rather than choosing.
        """
        best = self.suggestion
        if best is None:
            return []
        return [a for a in self.alternatives
                if a is not best and a.described and a.error <= ALIKE * best.error]

    def sentences(self) -> list[str]:
        """Say the verdict in lines: what fails, and what structure would describe it."""
        if self.described:
            return []
        lines = ["the model's structure does not describe these data; no effect is named:"]
        lines += [f'  {f.text}' for f in self.failed]
        lines += [f'  (also) {f.text}' for f in self.notes]
        best = self.suggestion
        if best is not None:
            fits = ', '.join(f'{k} {v:.1f} %' for k, v in best.fits.items())
            lines.append(f'  a structure that does: {best.description} (validated fits '
                         f'{fits}); state it in the parameters file and diagnose again')
            for other in self.alike:
                lines.append(f'  as well as it (normalised error {other.error:.3g} against '
                             f'{best.error:.3g}): {other.description}; these data cannot '
                             'tell them apart')
        elif self.alternatives:
            lines.append('  none of the structures tried describes them either: '
                         + '; '.join(f'{a.name} (normalised error {a.error:.2f})'
                                     for a in self.alternatives))
        return lines

    def to_json(self) -> dict[str, Any]:
        """Return the judgement as the JSON document carries it."""
        best = self.suggestion
        return {'described': self.described,
                'findings': [f.to_json() for f in self.findings],
                'alternatives': [a.to_json() for a in self.alternatives],
                'suggestion': None if best is None else best.name,
                'alike': [a.name for a in self.alike]}


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
