"""Whether the model's structure describes a record, judged before any effect is named.

Every effect of the library extends a model whose structure is right: a friction, a leakage
or a delay is a small departure from a plant that the baseline otherwise describes. On a rig
whose circuit the model does not have (a valve-switched or closed circuit, a motor at its
torque limit), the baseline absorbs the mismatch with values no rig has and the selection
then names whichever effect bends the wrong structure closest to the data: on the logs of a
real EHA with a one-way pump and a braking load cylinder it named kilonewtons of "Coulomb
friction" with tight intervals while the pressure's validated fit was negative. So the
structure is judged, on evidence a hydraulics engineer would use, each a
:class:`~exo_has_sim.diagnosis.findings.Finding`, in two stages:

- before any effect is searched for, the evidence the record gives of the circuit and the
  motor whatever effect it holds (:mod:`~exo_has_sim.diagnosis.evidence`): the
  direction-dependent flow gain, the record's against the model's (a circuit that feeds the
  rod chamber to retract moves faster per unit of pump flow that way by A_A/A_B, which no
  single flow gain of the paper's circuit can follow); the rod side (in the paper's circuit
  the rod chamber is the tank's; a measured ``pressure_b`` that carries load says it is a
  chamber of its own); the motor (a measured speed that falls short of settled commands is a
  torque or current limit, which the model's speed loop has not);
- then, of the model the verdict rests on (the baseline extended with the effects named, or
  the baseline alone), the validated fit of every measured output (:data:`FIT_THRESHOLDS`)
  and a bounded 95 % interval of every effect's size (:func:`fit_findings`). These are asked
  of that model rather than of the baseline before the effects: a hidden effect that the
  baseline lacks leaves such marks on it (on the first truth plant a dead zone left the
  position's fit at 72 %), which the effect, once named, takes away. A baseline parameter at
  a bound of its search, with an unbounded interval or far from the parameters file is
  reported, not gating: a right structure shows them too (the dead volume and the bulk
  modulus enter mostly as their ratio; a damping that a brake's force takes up goes to
  nothing; with a hidden effect the second truth plant's bulk modulus went to its bound).

A finding is gating or not: the gating ones decide
(:attr:`~exo_has_sim.diagnosis.findings.Judgement.described`); the others (a value far from the
parameters file, the residuals' whiteness) are reported beside them. A record that fails is
given the verdict "the model's structure does not describe these data", with the findings, and
the other structures the plant can take are fitted and ranked (:func:`try_structures`) to say
which would. The thresholds are set against the truth plants'
records, which the model's structure does describe (bench/detection.py ``--null``,
``--hidden``, ``--stated-limits`` and ``--third``; bench/README.md, "The structure judged
first").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from exo_has_sim.diagnosis.budget import TimeBudget
from exo_has_sim.diagnosis.compare import Span, Windows
from exo_has_sim.diagnosis.evidence import evidence, resisting_force
from exo_has_sim.diagnosis.findings import Alternative, Finding, Judgement
from exo_has_sim.diagnosis.fitting import (
    RUNAWAY,
    Evaluation,
    Fit,
    FitBudget,
    FloatArray,
    evaluate,
    fit_parameters,
    output_weights,
)
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.plants import WindowedModel
from exo_has_sim.diagnosis.selection import SECOND_START_REACH, Progress, Score, rank
from exo_has_sim.errors import DiagnosisError, FitError

#: Least validated fit [%] of each output, under the model the verdict rests on, for the
#: structure to count as describing the record.
FIT_THRESHOLDS = {'position': 80.0, 'pressure_a': 40.0, 'pressure_b': 20.0,
                  'motor_speed': 50.0}
#: A 95 % interval wider than this factor (high over low) is unbounded: the data do not
#: determine the parameter, which the structure then uses to absorb what it cannot follow.
INTERVAL_FACTOR = 1e3
#: A fitted value beyond this factor of the parameters file's (no prior), or beyond this many
#: prior standard deviations, is reported as far from it (not gating).
FAR_FACTOR = 10.0
FAR_SIGMAS = 4.0
#: Where a flow gain that differs by direction is all the evidence against the structure, it
#: decides the verdict only where a structure that routes the flow otherwise describes the
#: record with at most this share of the model's normalised error: a relief valve cracked 10
#: MPa below its setting (the first truth plant's seed 5005, position only) made a ratio of
#: 3.80 that no circuit predicted better (0.99 to 1.02 times the error, in two runs), and
#: one cracked at 4.2 MPa with the pressure measured (the second plant's 98003) 1.29, which
#: no circuit predicted better either (1.93 times the error); the valve-switched rig's 1.64
#: (the third plant's 9103, position only) is predicted by its own circuit with 0.14 times it.
AMBIGUOUS_GAIN = 0.5


def fit_findings(plant: WindowedModel, fit: Fit, validation: Evaluation) -> list[Finding]:
    """Judge a model's fit of every output and its parameters: at bounds, unbounded, far.

    An unbounded interval of the baseline's parameters is reported only (module docstring);
    of a named effect's parameter it gates: no verdict rests on a size the data do not
    determine.
    """
    baseline = {parameter.name for parameter in plant.baseline}
    out = []
    for k, output in enumerate(plant.outputs):
        threshold = FIT_THRESHOLDS.get(output, 0.0)
        value = validation.fit(k)
        out.append(Finding(f'fit:{output}', bool(value >= threshold), value, threshold,
                           f'{output}: validated fit {value:.1f} % (a right structure: at '
                           f'least {threshold:g} %)'))
    for parameter in fit.free:
        value = fit.values[parameter.name]
        if parameter.name in fit.at_bound:
            # Reported, not gating: on records the structure describes, a hidden effect drove
            # the bulk modulus to its bound (3e9 Pa) in the models of the second truth plant
            # with it; a damping or a leakage at its floor is one the data do not need.
            nil = parameter.negligible_floor and value < math.sqrt(parameter.lower
                                                                   * parameter.start)
            out.append(Finding(f'bound:{parameter.name}', False, value, math.nan,
                               f'{parameter.name} ended at a bound of its search, '
                               f'{value:.4g} {parameter.unit} ({parameter.description})'
                               + (': the data need none of it' if nil else ''),
                               gating=False))
        low, high = fit.interval.get(parameter.name, (-math.inf, math.inf))
        if parameter.log:
            width = high / low if low > 0.0 and math.isfinite(high) else math.inf
        else:
            # Compared before the exponential: a finite interval thousands of scales wide
            # overflowed it.
            spread = (high - low) / (parameter.scale or 1.0)
            width = math.exp(spread) if spread < math.log(INTERVAL_FACTOR) + 1.0 else math.inf
        if not width <= INTERVAL_FACTOR:
            out.append(Finding(f'interval:{parameter.name}', False, width, INTERVAL_FACTOR,
                               f'{parameter.name}: 95 % interval {low:.3g} to {high:.3g} '
                               f'{parameter.unit}, unbounded (the data do not determine it)',
                               gating=parameter.name not in baseline))
        if parameter.log and parameter.name != 'load_force':
            ratio = value / parameter.start
            sigmas = abs(math.log(ratio)) / parameter.prior if parameter.prior else math.nan
            far = sigmas > FAR_SIGMAS if parameter.prior else not (
                1.0 / FAR_FACTOR <= ratio <= FAR_FACTOR)
            if far:
                out.append(Finding(f'far:{parameter.name}', False, ratio, FAR_FACTOR,
                                   f'{parameter.name} fitted at {ratio:.3g} times the '
                                   f"parameters file's {parameter.start:.4g} "
                                   f'{parameter.unit}', gating=False))
    return out


def runaway(plant: WindowedModel, values: Mapping[str, float], span: Span,
            weights: FloatArray) -> Finding:
    """Say where a model cannot follow the record: the windows where its prediction runs away.

    Each window is simulated alone from the measured state with ``values``; it runs away where
    the simulation diverges or an output leaves the record by
    :data:`~exo_has_sim.diagnosis.fitting.RUNAWAY` times its spread (the fit's test of a
    start). A model the record's own inputs drive out of it, from the values its user gives,
    does not describe the record: this finding gates.
    """
    period = plant.measurement.period
    diverged: list[float] = []
    left: dict[str, list[float]] = {}
    for i in range(span.count):
        one = Span(span.starts[i:i + 1], span.horizon, span.burn_in)
        evaluation = evaluate(plant, [values], one, weights)[0]
        if not np.all(np.isfinite(evaluation.predicted)):
            diverged.append(float(span.starts[i] * period))
            continue
        worst = np.max(np.abs(evaluation.residuals), axis=(0, 1))
        if np.max(worst) >= RUNAWAY:
            left.setdefault(plant.outputs[int(np.argmax(worst))], []).append(
                float(span.starts[i] * period))
    gone = len(diverged) + sum(len(times) for times in left.values())
    share = gone / max(span.count, 1)

    def at(times: Sequence[float]) -> str:
        shown = ', '.join(f'{t:.2f}' for t in times[:4])
        return f'{shown}{", ..." if len(times) > 4 else ""} s'

    parts = [f'the simulation diverges in {len(diverged)} (from {at(diverged)})'] \
        if diverged else []
    parts += [f'{output} leaves the record by over {RUNAWAY:g} times its spread in '
              f'{len(times)} (from {at(times)})' for output, times in left.items()]
    text = (f"the model with the parameters file's values cannot follow the record: of "
            f'{span.count} windows, each simulated from the measured state, '
            + ('; '.join(parts) if parts else 'none runs away alone, but together they do')
            + ": a model the record's own inputs drive out of it does not describe it")
    return Finding('runaway', False, share, 0.0, text)


def judge(plant: WindowedModel, fit: Fit, validation: Evaluation, span: Span) -> Judgement:
    """Judge whether a fitted model's structure describes the record: both stages at once.

    Parameters
    ----------
    plant : WindowedModel
        The plant and its measurement.
    fit : Fit
        The model's fit.
    validation : Evaluation
        It on the validation windows.
    span : Span
        Every window.

    """
    return Judgement((*evidence(plant, span),
                      *fit_findings(plant, fit, validation)))


def output_fits(plant: WindowedModel, evaluation: Evaluation) -> dict[str, float]:
    """Return the validated fit [%] of each of the plant's outputs in an evaluation."""
    return {output: evaluation.fit(k) for k, output in enumerate(plant.outputs)}


def settle_ambiguous(plant: WindowedModel, judgement: Judgement, baseline: Fit,
                     validation: Evaluation, windows: Windows, weights: FloatArray,
                     effects: Sequence[str], progress: Progress | None = None,
                     budget: TimeBudget | None = None) -> Judgement:
    """Decide a flow gain by direction that is the only evidence against the structure.

    A loss at the loaded chamber's pressure slows one direction as a circuit that feeds the
    other chamber does: without a rodless pressure the regression of
    :func:`~exo_has_sim.diagnosis.flow_gains.flow_gains` cannot take it out, and with one it
    takes out most, not all, of a relief valve cracked far below its setting. Where that
    finding is the only one the structure fails, the plant's other structures are fitted
    (:func:`try_structures`): the verdict stands if one describes the record with at most
    :data:`AMBIGUOUS_GAIN` of the model's error (from its ``baseline`` fit's ``validation``),
    and the finding is reported only otherwise, saying why, for the effects to be searched.
    Without a pressure signal the model's error is also taken with each of ``effects`` (those
    the record cannot identify) that :data:`DIRECTION_MIMICS` lists fitted on top of it
    (:func:`_rival_effect`): a 28 N seal friction on a loaded hip slowed the extension through
    the leakage at its pressure, the flow gains differed by 1.40, and a closed circuit had 0.31
    of the paper circuit's error; such a record does not tell a circuit from an effect the
    signals cannot see. Any other judgement is returned as it is.
    """
    failed = judgement.failed
    if not isinstance(plant, HasPlant) or [f.check for f in failed] != ['direction_gain']:
        return judgement
    tried = try_structures(plant, judgement, windows, progress, budget)
    best = tried.suggestion
    own = normalised_error(output_fits(plant, validation), plant.outputs)
    pressure = plant.measurement.has('pressure_a')
    if best is None or best.error > AMBIGUOUS_GAIN * own:
        rival = None
    elif pressure:
        return tried
    else:
        rival = _rival_effect(plant, best, baseline, validation, windows, weights, effects,
                              progress, budget)
        if rival is None:
            return tried
        own = rival[1]
    best_share = (f'the best {min(a.error for a in tried.alternatives) / own:.2f}'
                  if tried.alternatives and own > 0.0 else 'none fitted')
    if pressure:
        why = ('a loss at the loaded pressure that the regression does not take out (a '
               'relief valve cracked far below its setting) gives such a ratio too')
        then = 'the effects are searched'
    else:
        why = ("without a pressure signal a loss at the loaded chamber's pressure (a relief "
               'valve, a leakage, a force that raises it) gives such a ratio too')
        then = 'record pressure_a to judge the circuit'
    against = "the model's error" if rival is None else f"the model's error with {rival[0]}"
    text = (f'{failed[0].text}; {why}, and no structure that routes the flow otherwise '
            f'predicts the record with at most {AMBIGUOUS_GAIN:g} times {against} '
            f'({best_share}): {then}')
    return Judgement(tuple(replace(f, gating=False, text=text) if f is failed[0] else f
                           for f in judgement.findings))


def _rival_effect(plant: HasPlant, best: Alternative, baseline: Fit, validation: Evaluation,
                  windows: Windows, weights: FloatArray, effects: Sequence[str],
                  progress: Progress | None,
                  budget: TimeBudget | None = None) -> tuple[str, float] | None:
    """Find the first of ``effects`` that, fitted on the model, leaves ``best`` no clear gain.

    Each is fitted jointly with the baseline's parameters (:func:`rank` with ``every``:
    from the nominal values too where the baseline strayed and the first fit came within
    :data:`~exo_has_sim.diagnosis.selection.SECOND_START_REACH` of the cost aimed at) on the
    budget ``best`` had (:data:`ALTERNATIVE_BUDGET`), until one has at most ``best``'s error
    over :data:`AMBIGUOUS_GAIN`.

    Returns
    -------
    tuple or None
        The effect and the model's normalised error with it; None if none comes so near.

    """
    reach = best.error / AMBIGUOUS_GAIN
    # A second start only where the first came near (the error is about the cost's root).
    near = math.sqrt(SECOND_START_REACH) * reach

    def error(score: Score) -> float:
        return normalised_error(output_fits(plant, score.validation), plant.outputs)

    if progress:
        progress(f'  {best.name}: the model with each effect, against it')
    for effect in (e for e in effects if e in DIRECTION_MIMICS):
        if budget is not None and not budget.allows(f'the model with {effect} against '
                                                    f'{best.name}'):
            continue
        score = rank(plant, baseline, validation, [], [effect], windows, weights, progress,
                     every=True, retry=lambda s: reach < error(s) <= near,
                     budget=ALTERNATIVE_BUDGET)[0]
        if error(score) <= reach:
            return effect, error(score)
    return None


def normalised_error(fits: Mapping[str, float], outputs: Sequence[str]) -> float:
    """Return the geometric mean of ``1 - fit / 100`` over the ``outputs`` that ``fits`` has.

    Structures are ranked by it (validated fits [%] per output); infinite where none is shared.
    """
    shared = [max(1.0 - fits[o] / 100.0, 1e-6) for o in outputs if o in fits]
    return math.exp(float(np.mean(np.log(shared)))) if shared else math.inf


CIRCUIT_TITLES = {
    'paper': "the paper's circuit (the pump between the tank and the rodless chamber)",
    'two_chamber': "the paper's pump with the rod side a chamber returning through a line",
    'closed': 'a closed circuit: the pump between the chambers, flow matching to a charge line',
    'switched': 'a one-way pump with direction valves, the other chamber draining to an '
                'accumulator'}


#: Effects that, unseen, make the flow gain differ by direction as another circuit does: a
#: loss at the loaded chamber's pressure, or a force that raises it where leakage follows the
#: pressure (entrained air changes the stiffness, not the flow either way settles to).
DIRECTION_MIMICS = ('coulomb_friction', 'braking_load', 'quadratic_leakage', 'relief_valve')
#: Fit budget of another structure, and of an effect it is weighed against
#: (:func:`~exo_has_sim.diagnosis.fitting.fit_parameters`): the same for both.
ALTERNATIVE_BUDGET: FitBudget = {'max_iterations': 6, 'tolerance': 1e-2}
#: A force resisting the motion both ways beyond this share of the peak thrust (and three
#: standard errors) is given to the structures tried as a brake to fit.
BRAKE_SHARE = 0.01


def candidate_structures(plant: HasPlant, judgement: Judgement) -> list[tuple[str, str,
                                                                              HasPlant]]:
    """List the other structures to fit: every other circuit, the measured speed as input.

    The measured speed becomes the input where the motor fell short of its commands (and
    with each other circuit then too); a force resisting the motion both ways
    (:func:`resisting_force`) becomes a brake of every structure, its size fitted.
    """
    short = any(f.check == 'motor_shortfall' for f in judgement.failed)
    speed = [False, True] if short and plant.measurement.has('motor_speed') else [False]
    brake = 0.0
    found = resisting_force(plant) if plant.params.brake_force <= 0.0 else None
    if found is not None and found[0] > max(3.0 * found[1],
                                            BRAKE_SHARE * plant.params.peak_thrust):
        brake = found[0]
    out = []
    for circuit in CIRCUIT_TITLES:
        for speed_input in speed:
            if circuit == plant.params.circuit and speed_input == plant.speed_input \
                    and not brake:
                continue
            name = f'circuit={circuit}' + (', motor_speed_input' if speed_input else '') \
                + (', brake' if brake else '')
            title = CIRCUIT_TITLES[circuit] + (', driven by the measured motor speed'
                                               if speed_input else '') \
                + (f', with a brake of about {brake:.0f} N' if brake else '')
            out.append((name, title, plant.restructured(circuit, speed_input, brake)))
    return out


def try_structures(plant: HasPlant, judgement: Judgement, windows: Windows,
                   progress: Progress | None = None,
                   budget: TimeBudget | None = None) -> Judgement:
    """Fit the plant's other structures to the record and rank them (best first).

    Each takes its own baseline fit (its weights made as the diagnosis makes them) and is
    judged by the same findings; they are ranked by their normalised error over the outputs
    they share with the plant. A spent ``budget`` skips the structures not yet fitted.
    """
    alternatives = []
    for name, title, other in candidate_structures(plant, judgement):
        if budget is not None and not budget.allows(f'the structure {name}'):
            continue
        if progress:
            progress(f'  fitting the structure {name}')
        weights = output_weights(other)
        try:
            fit = fit_parameters(other, other.baseline, {}, windows.estimation_span, weights,
                                 **ALTERNATIVE_BUDGET)
        except (FitError, DiagnosisError):
            continue
        validation = evaluate(other, [fit.values], windows.validation_span, weights)[0]
        fits = output_fits(other, validation)
        own = judge(other, fit, validation, windows.span)
        error = normalised_error(fits, plant.outputs)
        alternatives.append(Alternative(name, title, fits, error,
                                        {p.name: fit.values[p.name] for p in fit.free},
                                        own.findings))
        if progress:
            progress(f'    validated fits {", ".join(f"{k} {v:.1f} %" for k, v in fits.items())}'
                     f'{"" if own.described else " (not described either)"}')
    alternatives.sort(key=lambda a: (not a.described, a.error))
    return Judgement(judgement.findings, tuple(alternatives))
