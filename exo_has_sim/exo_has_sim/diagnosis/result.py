"""What a diagnosis found: the verdict, the causes and their sizes, the fits, the JSON document.

:class:`Diagnosis` is what :func:`~exo_has_sim.diagnosis.diagnose.diagnose` returns and what
:mod:`~exo_has_sim.diagnosis.report` writes: every model fitted on the way, with the verdict and
the document ``--json`` writes derived from them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from exo_has_sim.diagnosis.compare import Windows
from exo_has_sim.diagnosis.findings import Judgement
from exo_has_sim.diagnosis.fitting import Evaluation, Fit, FloatArray
from exo_has_sim.diagnosis.limits import DetectionLimit
from exo_has_sim.diagnosis.plants import WindowedModel
from exo_has_sim.diagnosis.residuals import CorrelationTest, Signature
from exo_has_sim.diagnosis.selection import Score, rivals
from exo_has_sim.diagnosis.transfer import ThirdOrderModel


@dataclass(frozen=True)
class Diagnosis:
    """What the model gets wrong, its named cause, and the extended model.

    Attributes
    ----------
    plant : WindowedModel
        The plant and its measurement.
    windows : Windows
        The windows and their split.
    weights : FloatArray
        Output weights of every cost.
    nominal : Evaluation
        The nominal model on the validation windows.
    baseline : Fit
        The baseline's re-estimated parameters.
    baseline_validation : Evaluation
        The baseline on the validation windows.
    steps : list[list[Score]]
        The ranking of every forward-selection step.
    causes : tuple[str, ...]
        The named effects, in the order they were added (empty for none).
    extended : Fit
        The model with the named effects (the baseline when none).
    extended_validation : Evaluation
        It on the validation windows.
    transfer : ThirdOrderModel or None
        The paper's third-order transfer function, when it could be identified.
    transfer_fit : float
        Its validated position fit [%] (NaN without it).
    tests : dict[str, CorrelationTest]
        ``baseline_auto``, ``baseline_cross``, ``extended_auto``, ``extended_cross``.
    signatures : list[Signature]
        The signatures of the candidate causes in the baseline's residuals.
    elapsed : float
        Wall time of the diagnosis [s].
    structure : tuple[str, ...]
        Alternative structures of the baseline the data called for
        (:attr:`~exo_has_sim.diagnosis.plants.WindowedModel.alternatives`), in the baseline.
    limits : dict[str, DetectionLimit]
        Each effect left out of the extended model, with the smallest size of it this record
        would have named (:mod:`~exo_has_sim.diagnosis.limits`).
    unidentifiable : dict[str, str]
        Effects the record's signals cannot identify, with the reason
        (:attr:`~exo_has_sim.diagnosis.plants.WindowedModel.unidentifiable`): never named, given no
        limits, only checked as rivals of what is named.
    hidden_rivals : dict[str, list[str]]
        Each named choice with the unidentifiable effects that explain the data as well
        (:func:`~exo_has_sim.diagnosis.selection.hidden_rivals`).
    judgement : Judgement or None
        Whether the baseline's structure describes the record, and, where not, the other
        structures fitted (:mod:`~exo_has_sim.diagnosis.structure`).
    untried : tuple[str, ...]
        The searches a spent time budget skipped (:mod:`~exo_has_sim.diagnosis.budget`).

    """

    plant: WindowedModel
    windows: Windows
    weights: FloatArray
    nominal: Evaluation
    baseline: Fit
    baseline_validation: Evaluation
    steps: list[list[Score]]
    causes: tuple[str, ...]
    extended: Fit
    extended_validation: Evaluation
    transfer: ThirdOrderModel | None
    transfer_fit: float
    tests: dict[str, CorrelationTest] = field(default_factory=dict)
    signatures: list[Signature] = field(default_factory=list)
    elapsed: float = 0.0
    structure: tuple[str, ...] = ()
    limits: dict[str, DetectionLimit] = field(default_factory=dict)
    unidentifiable: dict[str, str] = field(default_factory=dict)
    hidden_rivals: dict[str, list[str]] = field(default_factory=dict)
    judgement: Judgement | None = None
    untried: tuple[str, ...] = ()

    @property
    def described(self) -> bool:
        """Whether the model's structure describes the record (:attr:`judgement`)."""
        return self.judgement is None or self.judgement.described

    @property
    def verdict(self) -> str:
        """The verdict: ``'structure'``, ``'effect'`` (a cause named) or ``'none'``.

        ``'structure'``: the model's structure does not describe the data (:attr:`judgement`).
        """
        if not self.described:
            return 'structure'
        return 'effect' if self.causes else 'none'

    @property
    def cause(self) -> str:
        """The first named cause, or ``'none'``."""
        return self.causes[0] if self.causes else 'none'

    @property
    def rivals(self) -> dict[str, list[str]]:
        """Each choice (a cause or a structure) and what explains the data as well as it."""
        chosen = {step[0].effect for step in self.steps if step and step[0].significant}
        out = {}
        for step in self.steps:
            others = [e for e in rivals(step) if e not in chosen]
            others += [e for e in self.hidden_rivals.get(step[0].effect if step else '', [])
                       if e not in others]
            if others:
                out[step[0].effect] = others
        return out

    @property
    def indistinguishable(self) -> list[str]:
        """Effects and structures that explain the data as well as one chosen, each once.

        Two choices can share a rival (an unidentifiable relief valve beside a dead zone and
        beside the second-order loop taken after it); :attr:`rivals` keeps them per choice.
        """
        return list(dict.fromkeys(e for others in self.rivals.values() for e in others))

    @property
    def ranking(self) -> list[Score]:
        """The first step's ranking: every effect on top of the baseline."""
        return self.steps[0] if self.steps else []

    def fits(self) -> dict[str, dict[str, float | None]]:
        """Return the validated fit [%] of each output for each model (None: not finite)."""
        out = {}
        for name, evaluation in (('nominal', self.nominal), ('baseline', self.baseline_validation),
                                 ('extended', self.extended_validation)):
            out[name] = {output: _finite(evaluation.fit(k))
                         for k, output in enumerate(self.plant.outputs)}
        if self.transfer is not None:
            out['paper_transfer_function'] = {'position': _finite(self.transfer_fit)}
        return out

    def parameters(self) -> dict[str, dict[str, Any]]:
        """Return the extended model's fitted parameters with units and 95 % intervals."""
        out = {}
        starts = {p.name: p.start for p in self.plant.baseline}
        for parameter in self.extended.free:
            low, high = self.extended.interval.get(parameter.name, (math.nan, math.nan))
            out[parameter.name] = {
                'value': self.extended.values[parameter.name], 'unit': parameter.unit,
                'ci95': [_finite(low), _finite(high)],
                'nominal': starts.get(parameter.name),
                'description': parameter.description,
                'at_bound': parameter.name in self.extended.at_bound}
        return out

    def sizes(self) -> dict[str, float]:
        """Each named effect's size in its unit."""
        return {effect: self.extended.values[self.plant.effect_parameters(effect)[0].name]
                for effect in self.causes}

    def to_json(self) -> dict[str, Any]:
        """Return the document ``--json`` writes."""
        fits = self.fits()
        m = self.plant.measurement
        return {
            'verdict': self.verdict,
            'cause': self.cause,
            'causes': list(self.causes),
            'sizes': self.sizes(),
            'indistinguishable': self.indistinguishable,
            'unidentifiable': dict(self.unidentifiable),
            'baseline_structure': list(self.structure),
            'parameters': self.parameters(),
            'fit_baseline': fits['baseline']['position'],
            'fit_extended': fits['extended']['position'],
            'fits': fits,
            'ranking': [_ranking_row(score, self.plant) for score in self.ranking],
            'steps': [[_ranking_row(score, self.plant) for score in step]
                      for step in self.steps],
            'transfer_function': None if self.transfer is None else {
                'num': self.transfer.num.tolist(), 'den': self.transfer.den.tolist(),
                'poles': [[float(z.real), float(z.imag)] for z in self.transfer.poles()],
                'zeros': [[float(z.real), float(z.imag)] for z in self.transfer.zeros()],
                'velocity_gain': self.transfer.velocity_gain, 'fit': _finite(self.transfer_fit),
                'method': self.transfer.method, 'physical': not self.transfer.unphysical(),
                'unphysical': self.transfer.unphysical()},
            'structure': None if self.judgement is None else self.judgement.to_json(),
            'tests': {name: {'passed': test.passed, 'outside': test.outside,
                             'band': test.band} for name, test in self.tests.items()},
            'detection_limits': {effect: limit.to_json()
                                 for effect, limit in self.limits.items()},
            'data': {'source': m.source, 'plant': self.plant.kind, 'samples': m.samples,
                     'period': m.period, 'outputs': list(self.plant.outputs),
                     'horizon': self.windows.horizon * m.period,
                     'burn_in': self.windows.span.burn_in * m.period,
                     'estimation_windows': int(np.sum(~self.windows.validation)),
                     'validation_windows': int(np.sum(self.windows.validation)),
                     'notes': list(m.notes)},
            'elapsed': self.elapsed,
            'untried': list(self.untried),
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _ranking_row(score: Score, plant: WindowedModel) -> dict[str, Any]:
    size = plant.effect_parameters(score.effect)[0].name
    return {'effect': score.effect, 'fit': _finite(score.fit_percent), 'score': score.score,
            'cost_ratio': score.ratio, 'p_value': score.p_value,
            'significant': score.significant, 'size': score.fit.values[size],
            'unit': plant.effect_parameters(score.effect)[0].unit,
            'jointly_fitted': not score.screened}


def by_reason(unidentifiable: Mapping[str, str]) -> dict[str, list[str]]:
    """Group the effects the signals cannot identify by their reason: reason -> effect ids."""
    out: dict[str, list[str]] = {}
    for effect, why in unidentifiable.items():
        out.setdefault(why, []).append(effect)
    return out
