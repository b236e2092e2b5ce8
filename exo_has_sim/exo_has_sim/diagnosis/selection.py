"""Scoring the effects on held-out data, ranking them, and choosing the cause (or none).

Every effect is fitted jointly with the baseline's re-estimated parameters (an unmodelled effect
biases them: Coulomb friction is absorbed partly by the damping, a dead zone by the leakage) on
the estimation windows, then scored on the validation windows it has not seen, against the
baseline fitted on the same estimation windows. To keep that affordable, each effect's size
grid is first tried on the baseline (screening, :func:`rank`), and only the most promising one
or two are fitted jointly; a reference model (the baseline, a named extension) is converged
more tightly than a candidate, so that no candidate gains merely by converging further.

The criterion. ``V_o`` is the validation cost of output o (mean robust loss of its weighted
residuals; every output is weighted so that the baseline's robust RMS is 1). Residuals along a
window are correlated (an error accumulates), so the independent units are the validation
windows, n of them. With a variance of its own for each output, the log-likelihood ratio of
the extension is ``n sum_o ln(V_o,ext / V_o,ref)`` and the score is the Akaike criterion
``score = n sum_o ln(V_o,ext / V_o,ref) + 2 k`` for k added parameters: negative when the gain
pays for the parameters (an effect that shows in one output only, entrained air in the
pressure, counts fully). An effect is significant when, in addition, the one-sided t-test
across the windows of the per-window log ratio has p below :data:`ALPHA`, and the validated
cost (geometric mean over the outputs) falls by at least :data:`MIN_GAIN`: a gain too small to
matter, which a slightly wrong fixed parameter can produce without any effect, is no
diagnosis. The held-out windows already penalise an extension that only fits noise: fitted on
the estimation windows, it predicts the others worse. The named cause is the significant effect
of lowest score, or ``none``; before it is named, the reference is fitted again from the
effect's own values of the reference's parameters, and the effect must be significant against
that fit too (:func:`_against_own_start`): a joint fit may find a better basin of the
reference's own parameters, whose gain is then no effect's.

Two effects: forward selection. With a cause named, every other effect is fitted on top of the
extended model (baseline, first effect and the candidate, all refitted) and scored against the
extended model by the same rules; a significant one is named too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import t as t_distribution

from exo_has_sim.diagnosis.budget import TimeBudget
from exo_has_sim.diagnosis.compare import Span, Windows
from exo_has_sim.diagnosis.fitting import (
    Evaluation,
    Fit,
    FitBudget,
    FloatArray,
    evaluate,
    fit_parameters,
    robust_loss,
)
from exo_has_sim.diagnosis.plants import WindowedModel
from exo_has_sim.errors import FitError

#: Significance level of the t-test across the validation windows.
ALPHA = 0.01
#: Smallest relative fall of the validation cost (geometric mean over the outputs) that
#: counts as a gain.
MIN_GAIN = 0.05
#: Effects fitted jointly with the reference's parameters in each step (the best screened).
JOINT_FITS = 2
#: Smallest relative fall of the estimation cost at screening that earns a joint fit.
SCREEN_GAIN = 0.02
#: Relative cost change at which a reference model's fit stops (the candidates': the fitting
#: module's default, looser).
REFERENCE_TOLERANCE = 1e-4
#: A reference whose baseline parameters strayed beyond this factor of nominal gets a second
#: start for its joint fits (the parameters a HAS's data determine are +-30 % at most off).
STRAY_FACTOR = 1.5
#: Screening tries the grids on one estimation window in this many. Every one: on half of
#: them the projection fitted the reference's parameters to those windows alone, and where
#: the model was far off (a relief valve cracking 10 MPa below its setting, unmodelled) that
#: alone took their cost from 0.99 to 0.27, every effect's with it, and the effect was never
#: fitted; on all of them it was named (7.45 MPa against 7.69).
SCREEN_STRIDE = 1
#: A runner-up is fitted jointly too only if its screened cost is within this factor of the
#: best's (a rival explanation, as quadratic leakage is for a cracked relief valve).
RIVAL_FACTOR = 2.0
#: A fit that must come near a cost to matter (a rival's, the named effect's validated cost;
#: another structure's error) gets its second start only if its first left at most this
#: factor of that cost: the largest gain of a second start measured was 2.9 times the cost
#: (a rival of the first plant's 5009 dead zone from its position, which still stayed 89
#: times the dead zone's), the friction in :func:`hidden_rivals`'s docstring 2.5 times.
SECOND_START_REACH = 4.0

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Score:
    """An extension fitted and scored on the validation windows.

    Attributes
    ----------
    effects : tuple[str, ...]
        Effects of the extension (the ones already named, then the candidate).
    fit : Fit
        Joint fit of the baseline's and the effects' parameters.
    validation : Evaluation
        Predictions on the validation windows.
    reference : Evaluation
        Predictions of the model it extends on the same windows.
    added : int
        Parameters added.
    screened : bool
        Scored at its best size on the reference held fixed, not fitted jointly.
    own_start : bool
        Scored against the reference re-fitted from its own values (:func:`_against_own_start`)
        after it had been significant against the reference.

    """

    effects: tuple[str, ...]
    fit: Fit
    validation: Evaluation
    reference: Evaluation
    added: int
    screened: bool = False
    own_start: bool = False

    @property
    def effect(self) -> str:
        """The candidate effect (the last one added)."""
        return self.effects[-1]

    @property
    def windows(self) -> int:
        """Validation windows, the independent units of the test."""
        return int(self.validation.residuals.shape[0])

    @property
    def output_ratios(self) -> FloatArray:
        """Validation cost of each output over the reference's."""
        return np.asarray(self.validation.output_costs() / self.reference.output_costs(),
                          dtype=float)

    @property
    def log_ratio(self) -> float:
        """Sum over the outputs of the log of their validation cost ratios."""
        return float(np.sum(np.log(np.maximum(self.output_ratios, 1e-300))))

    @property
    def ratio(self) -> float:
        """Validation cost over the reference's, the geometric mean over the outputs."""
        return math.exp(self.log_ratio / len(self.output_ratios))

    @property
    def score(self) -> float:
        """AIC difference with the windows as samples; negative is better than without.

        Each output has a variance of its own, so the log-likelihood ratio is the sum of the
        outputs' log cost ratios times the number of windows.
        """
        return self.windows * self.log_ratio + 2.0 * self.added

    @property
    def p_value(self) -> float:
        """One-sided p of the t-test that the per-window log cost ratio is negative.

        A window's log ratio is summed over the outputs, as the score's.
        """
        return _paired_p(self.validation, self.reference)

    @property
    def significant(self) -> bool:
        """Whether the gain is significant by every rule (module docstring)."""
        return (not self.screened and self.score < 0.0 and self.p_value < ALPHA
                and self.ratio <= 1.0 - MIN_GAIN)

    @property
    def fit_percent(self) -> float:
        """Validated position fit [%]."""
        return self.validation.fit(0)


def _screen(plant: WindowedModel, reference: Fit, effects: Sequence[str], windows: Windows,
            weights: FloatArray) -> tuple[dict[str, tuple[dict[str, float], float]], float]:
    """Try each effect's size grid on the reference model (one plant call).

    The reference's own parameters would partly absorb an effect (a quadratic leakage raises
    the fitted linear one): tried on top of them unchanged, the effect would look useless. So
    each grid point's residual ``r`` gets the reference's parameters re-fitted to first order
    with the reference's Jacobian J, ``r - J pinv(J) r`` (variable projection, linearised),
    and is judged by that projected cost, against the reference's own residual projected so.
    Where the projection moves the reference far (its fit ended far from the linearised
    optimum: with a relief valve cracked far below its setting unmodelled, the projection
    alone took the cost from 0.99 to 0.27, and every effect to within 10 % of that, whatever
    it did), the projected costs carry little; so an effect also counts by its raw cost on the
    unmoved reference, against the reference's, and the better of the two relative gains
    decides (that effect's raw cost was 0.19 of the reference's). Screening only chooses what
    to fit, so it uses one estimation window in :data:`SCREEN_STRIDE`.

    Returns
    -------
    tuple
        Per effect, the best grid point's values (the reference's, moved by the projection
        where the projected gain decides, and the effect's) and its cost: the reference's
        cost times the better relative gain; and the reference's cost on the same windows.

    """
    estimation = windows.estimation_span
    keep = np.arange(estimation.count) % SCREEN_STRIDE == 0
    span = Span(estimation.starts[keep], estimation.horizon, estimation.burn_in)
    candidates: list[dict[str, float]] = []
    owners: list[str] = []
    for effect in effects:
        added = plant.effect_parameters(effect)
        others = {p.name: p.start for p in added[1:]}
        for value in added[0].grid or (added[0].start,):
            candidates.append(reference.values | others | {added[0].name: value})
            owners.append(effect)
    # The grid's points are linearised at the reference (a window's unmeasured load,
    # WindowedModel.predict): half the simulations, and screening only chooses what to fit.
    evaluations = evaluate(plant, candidates, span, weights, linearised_at=reference.values)
    jacobian, solve = None, None
    if reference.jacobian is not None and reference.jacobian.size:
        columns = reference.jacobian.shape[1]
        jacobian = reference.jacobian.reshape(estimation.count, -1, columns)[keep] \
            .reshape(-1, columns)
        solve = np.linalg.pinv(jacobian)
    if reference.residual is not None:
        own = reference.residual.reshape(estimation.count, -1)[keep].ravel()
    else:
        own = evaluate(plant, [reference.values], span, weights)[0].residuals.ravel()
    reference_cost = float(np.mean(robust_loss(own)))
    projected_cost = reference_cost
    if solve is not None and jacobian is not None and np.all(np.isfinite(own)):
        projected_cost = float(np.mean(robust_loss(own - jacobian @ (solve @ own))))
    best: dict[str, tuple[dict[str, float], float]] = {}
    for effect, values, evaluation in zip(owners, candidates, evaluations, strict=True):
        r = evaluation.residuals.ravel()
        if not np.all(np.isfinite(r)):
            continue
        values = dict(values)
        raw = float(np.mean(robust_loss(r)))
        gain = raw / max(reference_cost, 1e-300)
        if solve is not None and jacobian is not None:
            step = -solve @ r
            projected = float(np.mean(robust_loss(r + jacobian @ step)))
            if projected / max(projected_cost, 1e-300) < gain:
                gain = projected / max(projected_cost, 1e-300)
                for parameter, z in zip(reference.free, step, strict=True):
                    values[parameter.name] = parameter.moved(values[parameter.name],
                                                             float(z))
        cost = gain * reference_cost
        if effect not in best or cost < best[effect][1]:
            best[effect] = (values, cost)
    for effect in effects:  # every grid point diverged: the reference's values, no gain
        best.setdefault(effect, (reference.values | {p.name: p.start for p in
                                                     plant.effect_parameters(effect)},
                                 math.inf))
    return best, reference_cost


def _strays(plant: WindowedModel, reference: Fit) -> dict[str, float]:
    """Return the baseline parameters beyond :data:`STRAY_FACTOR` of their start, at it."""
    out = {}
    for parameter in plant.baseline:
        value = reference.values.get(parameter.name, parameter.start)
        if parameter.scale is None and not (parameter.start / STRAY_FACTOR <= value
                                            <= parameter.start * STRAY_FACTOR):
            out[parameter.name] = parameter.start
    return out


def _strayed(plant: WindowedModel, reference: Fit) -> bool:
    """Tell whether a baseline parameter lies beyond :data:`STRAY_FACTOR` of its start."""
    return bool(_strays(plant, reference))


def rank(plant: WindowedModel, reference: Fit, reference_validation: Evaluation,
         named: Sequence[str], effects: Sequence[str], windows: Windows, weights: FloatArray,
         progress: Progress | None = None, every: bool = False,
         retry: Callable[[Score], bool] | None = None,
         budget: FitBudget | None = None) -> list[Score]:
    """Score every effect on top of a reference model; best score first.

    Each effect's size grid is tried on the reference held fixed (screening); the
    :data:`JOINT_FITS` effects whose best grid point lowers the estimation cost most, by at
    least :data:`SCREEN_GAIN` and to within :data:`RIVAL_FACTOR` of the best, are then fitted
    jointly with the reference's parameters (``every``: all of them, whatever screening
    found, each also from the nominal values where the reference strayed and ``retry``, if
    given, holds the first fit worth a second start). The others are scored at their best
    grid point (``Score.screened``), which can only flatter them less than a joint fit would,
    and cannot be named. ``budget``: the joint fits' ``max_iterations`` and ``tolerance``
    (:func:`~exo_has_sim.diagnosis.fitting.fit_parameters`), where not the defaults.
    """
    budget = budget or {}
    if progress:
        progress(f'  trying the size grids of {len(effects)} effects')
    screened, reference_cost = _screen(plant, reference, effects, windows, weights)
    strays = _strays(plant, reference)
    if strays:
        # The reference's parameters strayed from nominal to absorb something (a motor lag
        # five times its file's value taking up an 18 ms delay): tried on top of them, the
        # effect that they absorb looks useless. So each grid is tried with each strayed
        # parameter back at its nominal value too, and the best screening counts.
        for name, start in strays.items():
            reset, _ = _screen(plant, Fit(reference.values | {name: start}, reference.free),
                               effects, windows, weights)
            screened = {e: min(screened[e], reset[e], key=lambda item: item[1])
                        for e in effects}
    order = sorted(effects, key=lambda e: screened[e][1])
    best = screened[order[0]][1]
    joint = order if every else [e for e in order[:JOINT_FITS]
                                 if screened[e][1] <= (1.0 - SCREEN_GAIN) * reference_cost
                                 and screened[e][1] <= RIVAL_FACTOR * best]
    rest = [e for e in effects if e not in joint]
    strayed = _strayed(plant, reference)
    validations = evaluate(plant, [screened[e][0] for e in rest], windows.validation_span,
                           weights) if rest else []
    ranking = []
    # A screened effect is scored at its grid point, with the reference's values projected.
    for effect, validation in zip(rest, validations, strict=True):
        ranking.append(_at_grid_point(plant, named, effect, screened[effect],
                                      reference_validation, validation))
    for effect in joint:
        added = plant.effect_parameters(effect)
        if progress:
            progress(f'  fitting {effect} jointly with '
                     f'{", ".join(p.name for p in reference.free)}')
        free = (*reference.free, *added)
        sizes = {p.name: screened[effect][0][p.name] for p in added}
        try:
            fit = fit_parameters(plant, free, {}, windows.estimation_span, weights,
                                 initial=screened[effect][0], **budget)
        except FitError:
            # The first-order projection can move the reference's values where the plant
            # cannot be simulated (a soft oil and a fast motor): start from them unmoved,
            # at the size screening chose, which it did simulate.
            try:
                fit = fit_parameters(plant, free, {}, windows.estimation_span, weights,
                                     initial=reference.values | sizes, **budget)
            except FitError:
                # Neither start simulates all windows (a 9 kN brake on an oil fitted soft ran
                # away from a rig's record): no joint fit, the grid point's score, which
                # cannot be named. The record still gets its verdict.
                validation = evaluate(plant, [screened[effect][0]], windows.validation_span,
                                      weights)[0]
                ranking.append(_at_grid_point(plant, named, effect, screened[effect],
                                              reference_validation, validation))
                continue
        validation = evaluate(plant, [fit.values], windows.validation_span, weights)[0]
        score = Score((*named, effect), fit, validation, reference_validation, len(added))
        if (every or effect == order[0]) and strayed \
                and (retry is None or retry(score)):
            # The reference's parameters strayed from nominal to absorb the effect: from
            # there the joint fit can stall in their valley (a bulk modulus pinned high by a
            # dead zone), so the likeliest effect's fit also starts from the nominal values,
            # and the better one wins.
            try:
                again = fit_parameters(plant, free, {}, windows.estimation_span, weights,
                                       initial=reference.values | plant.nominal() | sizes,
                                       **budget)
            except FitError:  # the nominal start runs away: the first fit stands
                again = fit
            if again.cost < fit.cost:
                validation = evaluate(plant, [again.values], windows.validation_span,
                                      weights)[0]
                score = replace(score, fit=again, validation=validation)
        ranking.append(score)
    ranking.sort(key=lambda s: s.score)
    if progress:
        for score in ranking:
            size = plant.effect_parameters(score.effect)[0].name
            how = 'grid' if score.screened else 'fit '
            progress(f'  {" + ".join(score.effects):<38} {how} validated cost '
                     f'x{score.ratio:.3f} score {score.score:+7.1f} p {score.p_value:.1e} '
                     f'size {score.fit.values[size]:.4g}')
    return ranking


def _at_grid_point(plant: WindowedModel, named: Sequence[str], effect: str,
                   point: tuple[dict[str, float], float], reference_validation: Evaluation,
                   validation: Evaluation) -> Score:
    """Score an effect at its best grid point (``point``: values, cost): not to be named."""
    added = plant.effect_parameters(effect)
    return Score((*named, effect), Fit(point[0], added, {}, point[1]), validation,
                 reference_validation, len(added), screened=True)


def rivals(ranking: Sequence[Score]) -> list[str]:
    """Effects of a ranking that explain the data as well as its named first one.

    A rival is significant on its own (fitted jointly, every rule of :attr:`Score.significant`)
    and the named effect does not predict the validation windows better than it: the
    one-sided t-test across the windows of the log ratio of their costs (summed over the
    outputs) has p of at least :data:`ALPHA`. Without the outputs that tell them apart
    (the pressure, for a leakage and a cracked relief valve), such effects cannot be told
    apart in the data, and a verdict says so instead of choosing.
    """
    if not ranking or not ranking[0].significant:
        return []
    best = ranking[0]
    return [score.effect for score in ranking[1:]
            if score.significant and _paired_p(best.validation, score.validation) >= ALPHA]


def hidden_rivals(plant: WindowedModel, steps: Sequence[Sequence[Score]], baseline: Fit,
                  baseline_validation: Evaluation, windows: Windows, weights: FloatArray,
                  effects: Sequence[str], progress: Progress | None = None,
                  ) -> dict[str, list[str]]:
    """Effects among ``effects`` that explain what a named choice explains as well.

    The diagnosis passes those the signals cannot identify and, without a pressure signal,
    every other effect too. An unidentifiable one
    (:attr:`~exo_has_sim.diagnosis.plants.WindowedModel.unidentifiable`) is never named, but it may
    still produce what a named one is named for: in a record of the
    position alone, friction moves the pressure at each reversal, and the leakage turns that
    into lost motion, as a dead zone or a delay would. So each step's named choice is checked
    against them: each is fitted jointly on top of the step's reference, and again from the
    nominal values where the reference's parameters strayed and the first fit is no rival
    but left at most :data:`SECOND_START_REACH` times the choice's validated cost
    (:func:`rank` with ``every``).
    Less would miss them: for a 95 N friction in a squat, screening's first-order projection
    judged the friction 70 times worse than none, and a fit from the reference, whose leakage
    had grown 13-fold, stopped at 33 N and x0.89 of the cost, behind the 3.6 rad/s dead zone
    named (x0.85); from the nominal values it reached 67 N and x0.36. One that lowers the
    validated cost and that the choice does not beat (:func:`rivals`'s t-test) is its rival:
    unlike a rival that could be named, it need not pass the naming rules itself, since the
    question is only whether the choice explains the data better than it.

    Returns
    -------
    dict[str, list[str]]
        Each named choice with its rivals among ``effects`` (only those that have any).

    """
    out: dict[str, list[str]] = {}
    if not effects:
        return out
    reference, reference_validation = baseline, baseline_validation
    named: list[str] = []
    for step in steps:
        best = step[0] if step else None
        if best is None or not best.significant:
            break
        if progress:
            progress(f'checking {best.effect} against what these signals cannot identify')
        def rival(score: Score, best: Score = best) -> bool:
            return score.ratio < 1.0 and _paired_p(best.validation, score.validation) >= ALPHA

        # A fit that is a rival already needs no second start (a better fit stays one), nor
        # one that left the named effect's cost far out of reach.
        def retry(score: Score, best: Score = best) -> bool:
            return not rival(score) and score.ratio <= SECOND_START_REACH * best.ratio

        others = [e for e in effects if e != best.effect and e not in named]
        if not others:
            named.append(best.effect)
            reference, reference_validation = best.fit, best.validation
            continue
        ranking = rank(plant, reference, reference_validation, named, others, windows,
                       weights, progress, every=True, retry=retry)
        found = [score.effect for score in ranking if rival(score)]  # each fitted jointly
        if found:
            out[best.effect] = found
        named.append(best.effect)
        reference, reference_validation = best.fit, best.validation
    return out


def _paired_p(better: Evaluation, other: Evaluation) -> float:
    """One-sided p of the t-test that ``better`` has lower window costs than ``other``."""
    ratios = np.sum(np.log(np.maximum(better.window_output_costs(), 1e-300)
                           / np.maximum(other.window_output_costs(), 1e-300)), axis=1)
    n = len(ratios)
    mean = float(np.mean(ratios))
    spread = float(np.std(ratios, ddof=1)) if n > 1 else math.inf
    if mean >= 0.0:
        return 1.0
    if spread == 0.0:
        return 0.0
    return float(t_distribution.cdf(mean / (spread / math.sqrt(n)), n - 1))


def _against_own_start(plant: WindowedModel, score: Score, reference: Fit, windows: Windows,
                       weights: FloatArray) -> Score:
    """Score an extension against its reference re-fitted from the extension's own values.

    A joint fit starts elsewhere than the reference's fit did and can end in another basin
    of the reference's own parameters, which predicts the held-out windows better whatever
    the effect does: on an effect-free record of the second truth plant (command and
    position only, seed 70011), a dead zone of 0.05 rad/s, which moves nothing, came with a
    validated cost of x0.73 of the baseline's; against the baseline re-fitted from that fit's
    values, without the dead zone, it was x0.96 and not significant. So the reference is
    re-fitted from the extension's values of its parameters, and the extension is scored
    against that too: an effect is named only where it beats the reference from either
    start.
    """
    names = {parameter.name for parameter in reference.free}
    start = reference.values | {k: v for k, v in score.fit.values.items() if k in names}
    try:
        again = fit_parameters(plant, reference.free, {}, windows.estimation_span, weights,
                               initial=start, tolerance=REFERENCE_TOLERANCE)
    except FitError:
        return score
    validation = evaluate(plant, [again.values], windows.validation_span, weights)[0]
    return replace(score, reference=validation, own_start=True)


def forward_selection(plant: WindowedModel, baseline: Fit, baseline_validation: Evaluation,
                      windows: Windows, weights: FloatArray, effects: Sequence[str],
                      max_causes: int = 2, progress: Progress | None = None,
                      budget: TimeBudget | None = None) -> list[list[Score]]:
    """Rank the effects, name the best significant one, and repeat on the extended model.

    The plant's alternative structures (:attr:`WindowedModel.alternatives`) compete in every
    ranking with the effects, by the same rules, so that neither takes what the other explains
    better (a second-order motor loop and a transport delay both delay the response); one
    taken extends the model as an effect does but is no cause and does not count against
    ``max_causes``. Where the data cannot tell a structure from an effect, the better-ranked
    goes first and the other is reported as indistinguishable (:func:`rivals`): with the
    structure first, no alarm is raised for what may be the nominal model's shape (a false
    alarm rate of 1 in 40 on the null ensemble of bench/detection.py against 3 in 40 when
    the effect went first).

    Returns
    -------
    list[list[Score]]
        One ranking per step (best score first); step k's first entry is the k-th cause when
        it is significant. The steps end with the first ranking without a significant effect,
        or before a step a spent ``budget`` skips (the first step always runs).

    """
    steps: list[list[Score]] = []
    reference, reference_validation = baseline, baseline_validation
    named: list[str] = []
    structures = set(plant.alternatives)
    remaining = [*effects, *structures.difference(effects)]
    while remaining and sum(e not in structures for e in named) < max_causes:
        if steps and budget is not None \
                and not budget.allows(f'step {len(steps) + 1} of the selection'):
            break
        if progress:
            progress(f'step {len(steps) + 1}: each effect on top of '
                     f'{" + ".join(["baseline", *named])}')
        ranking = rank(plant, reference, reference_validation, named, remaining, windows,
                       weights, progress)
        steps.append(ranking)
        checked: set[str] = set()
        while ranking[0].significant and ranking[0].effect not in checked:
            checked.add(ranking[0].effect)
            again = _against_own_start(plant, ranking[0], reference, windows, weights)
            if again.significant:
                break
            if progress:
                progress(f'  {ranking[0].effect}: the reference re-fitted from its values does '
                         f'as well (validated cost x{again.ratio:.3f} against it): not named')
            ranking[0] = again
            ranking.sort(key=lambda score: score.score)
        best = ranking[0]
        if not best.significant:
            break
        # The named model becomes the next step's reference: converge it tightly, or the
        # next candidates would gain merely by converging further.
        polished = fit_parameters(plant, best.fit.free, {}, windows.estimation_span, weights,
                                  initial=best.fit.values, tolerance=REFERENCE_TOLERANCE)
        if polished.cost <= best.fit.cost:
            validation = evaluate(plant, [polished.values], windows.validation_span,
                                  weights)[0]
            best = replace(best, fit=polished, validation=validation)
            ranking[0] = best
        named.append(best.effect)
        remaining.remove(best.effect)
        reference, reference_validation = best.fit, best.validation
    return steps
