"""The diagnosis report: Markdown with PNG plots, and the text summary the command prints.

``write_report(diagnosis, folder)`` writes ``report.md`` and its plots into the folder:
predictions against the measurement on validation windows (nominal, baseline, extended and
the paper's transfer function), the effect ranking, the residual tests with their 99 % bands,
and the signatures of the candidate causes. Matplotlib runs with the Agg backend (no display).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from exo_has_sim.diagnosis.effects import EFFECTS, effect_title
from exo_has_sim.diagnosis.result import Diagnosis, by_reason
from exo_has_sim.diagnosis.selection import ALPHA, MIN_GAIN

#: Validation windows shown in the prediction plot.
SHOWN_WINDOWS = 4
UNITS = {'position': ('mm', 1e3), 'pressure_a': ('MPa', 1e-6), 'pressure_b': ('MPa', 1e-6),
         'motor_speed': ('rad/s', 1.0)}
#: Unit of each plant's input (:data:`exo_has_sim.diagnosis.data.INPUT_COLUMNS`).
INPUT_UNITS = {'motor_speed_command': 'rad/s', 'force': 'N'}
#: Least span of a prediction plot's y axis, as a share of the output's range over the windows
#: shown: a still window's flat signal is drawn flat, not magnified to its last digits.
LEAST_SPAN = 0.05
#: SI prefixes an axis' unit may take, by power of 1000.
PREFIXES = {-3: 'n', -2: 'µ', -1: 'm', 0: '', 1: 'k', 2: 'M', 3: 'G'}
#: Units that take a prefix on an axis (the base units the diagnosis plots in).
PREFIXED_UNITS = ('m', 'm/s', 'Pa', 'Pa/s', 'N', 's')


def summary(diagnosis: Diagnosis) -> str:
    """Summarise in a few lines: the cause, its size and interval, the validated fits."""
    fits = diagnosis.fits()
    judgement = diagnosis.judgement
    if judgement is not None and not diagnosis.described:
        lines = ['verdict: structure', *judgement.sentences()]
    else:
        lines = [_cause_line(diagnosis)]
        if not diagnosis.causes:
            lines += [f'  {line}' for line in _unjudged(diagnosis)]
        if judgement is not None:
            # A finding that fails is shown whether it decides or not: a "none" beside it
            # is no all-clear.
            lines += [f'  finding: {f.text}' for f in judgement.notes]
    if diagnosis.structure:
        lines.append(f'baseline structure: {", ".join(diagnosis.structure)} (the data call '
                     'for it; not a cause)')
    parameters = diagnosis.parameters()
    for effect, size in diagnosis.sizes().items():
        name = diagnosis.plant.effect_parameters(effect)[0].name
        low, high = parameters[name]['ci95']
        unit = parameters[name]['unit']
        lines.append(f'  {effect}: {size:.4g} {unit} (95 % interval {_number(low)} to '
                     f'{_number(high)})')
    for choice, others in diagnosis.rivals.items():
        lines.append(f'  indistinguishable from {choice} in these data: {", ".join(others)} '
                     f'({_missing(diagnosis)})')
    if diagnosis.causes or not diagnosis.described:
        for why, effects in by_reason(diagnosis.unidentifiable).items():
            titles = ', '.join(effect_title(e) for e in effects)
            lines.append(f'not identifiable from these signals, never named: {titles} ({why})')
    for output in diagnosis.plant.outputs:
        lines.append(f'validated {output} fit: nominal {_percent(fits["nominal"][output])}, '
                     f'baseline {_percent(fits["baseline"][output])}, extended '
                     f'{_percent(fits["extended"][output])}')
    if diagnosis.transfer is not None:
        lines.append(f"paper's third-order transfer function: position fit "
                     f'{diagnosis.transfer_fit:.2f} %')
        lines.extend(f'  not a physical model of the HAS, whatever its fit: {why}'
                     for why in diagnosis.transfer.unphysical())
    if diagnosis.untried:
        lines.append('the time budget ended the search; not tried: '
                     + '; '.join(diagnosis.untried))
    if diagnosis.limits:
        lines.append('detection limits in these data (effects left out):')
        lines.extend(f'  {limit.sentence()}' for limit in diagnosis.limits.values()
                     if limit.stated)
        unstated = [effect_title(e) for e, limit in diagnosis.limits.items() if not limit.stated]
        if unstated:
            lines.append(f'  no limit is stated for {", ".join(unstated)}: on the truth plants '
                         'the limit found so held in fewer than 80 % of records')
    return '\n'.join(lines)


def _cause_line(diagnosis: Diagnosis) -> str:
    """Say the cause; a "none" says at once whether it is an all-clear."""
    if diagnosis.causes:
        return f'cause: {", ".join(diagnosis.causes)}'
    failed = [] if diagnosis.judgement is None else diagnosis.judgement.notes
    lacking = _lacking(diagnosis)
    caveats = []
    if failed:
        caveats.append(f'{len(failed)} finding{"s" if len(failed) > 1 else ""} on the '
                       'structure failed (below)')
    if diagnosis.unidentifiable or lacking:
        caveats.append('some effects could not be judged from these signals (below)')
    if not caveats:
        return 'cause: none'
    return f'cause: none, and not an all-clear: {"; ".join(caveats)}'


def _lacking(diagnosis: Diagnosis) -> list[str]:
    """Return the HAS signals the record lacks that would judge more of it."""
    if diagnosis.plant.kind != 'has':
        return []
    return [name for name in ('pressure_a', 'motor_speed') if name not in diagnosis.plant.outputs]


def _unjudged(diagnosis: Diagnosis) -> list[str]:
    """Say what a record that named nothing could not judge, and which sensor would."""
    lines = []
    for why, effects in by_reason(diagnosis.unidentifiable).items():
        lines.append(f'not judged: {", ".join(effect_title(e) for e in effects)} ({why})')
    lacking = _lacking(diagnosis)
    if lacking:
        lines.append(f'a record with {" and ".join(lacking)} would judge '
                     + ('them' if diagnosis.unidentifiable else 'the model more closely'))
    return lines


def _missing(diagnosis: Diagnosis) -> str:
    """Say what the record lacks that could tell rival causes apart."""
    lacking = _lacking(diagnosis)
    if not lacking:
        return 'they predict the held-out data equally well'
    return f'they predict the held-out data equally well; a record with {" and ".join(lacking)} ' \
           'could tell them apart'


def _percent(value: float | None) -> str:
    """Say a fit [%]; one that cannot be computed is a prediction that ran away."""
    return 'none (the prediction ran away)' if value is None or not math.isfinite(value) \
        else f'{value:.2f} %'


def _number(value: float | None) -> str:
    return 'unbounded' if value is None or not math.isfinite(value) else f'{value:.4g}'


def write_json(diagnosis: Diagnosis, path: Path) -> None:
    """Write the JSON document of :meth:`Diagnosis.to_json`."""
    path.write_text(json.dumps(diagnosis.to_json(), indent=1, default=_jsonable) + '\n',
                    encoding='utf-8')


def document(diagnosis: Diagnosis) -> dict[str, Any]:
    """Return the document of :meth:`Diagnosis.to_json` in plain Python types, as JSON reads it.

    What a worker process hands back: it pickles anywhere and compares equal to what
    :func:`write_json` wrote once read.
    """
    doc: dict[str, Any] = json.loads(json.dumps(diagnosis.to_json(), default=_jsonable))
    return doc


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    msg = f'cannot write {type(value).__name__} as JSON'
    raise TypeError(msg)


def write_report(diagnosis: Diagnosis, folder: Path, title: str | None = None) -> Path:
    """Write ``report.md`` and its PNG plots into ``folder``; return the report's path."""
    import matplotlib as mpl

    mpl.use('Agg')
    folder.mkdir(parents=True, exist_ok=True)
    _plot_predictions(diagnosis, folder / 'predictions.png')
    _plot_ranking(diagnosis, folder / 'ranking.png')
    _plot_tests(diagnosis, folder / 'residual_tests.png')
    _plot_signatures(diagnosis, folder / 'signatures.png')
    path = folder / 'report.md'
    path.write_text(_markdown(diagnosis, title), encoding='utf-8')
    return path


def _markdown(diagnosis: Diagnosis, title: str | None) -> str:
    d = diagnosis
    m = d.plant.measurement
    doc = d.to_json()
    data = doc['data']
    out = [f'# {title or "Model-error diagnosis"}', '',
           f'Data: `{m.source}`, {m.samples} samples at {1.0 / m.period:.4g} Hz '
           f'({m.duration:.1f} s); plant `{d.plant.kind}`; outputs compared: '
           f'{", ".join(d.plant.outputs)}.', '']
    for note in m.notes:
        out.append(f'- {note}')
    out += ['', '## Verdict', '']
    if d.judgement is not None and not d.described:
        out += ["**The model's structure does not describe these data**: no effect is named, "
                'since an effect of the library extends a model whose structure is right.', '',
                '| finding | value | threshold |', '|---|---|---|']
        out += [f'| {f.text} | {_number(f.value)} | {_number(f.threshold)} |'
                for f in d.judgement.failed + d.judgement.notes]
        if d.judgement.alternatives:
            outputs = d.plant.outputs
            out += ['', 'The structures the plant can take instead, fitted to the record (best '
                    'first; validated fits [%]):', '',
                    '| structure | ' + ' | '.join(outputs) + ' | describes the data |',
                    '|---|' + '---|' * (len(outputs) + 1)]
            out += [f'| {a.description} | ' + ' | '.join(
                '-' if o not in a.fits else f'{a.fits[o]:.1f}' for o in outputs)
                + f' | {"yes" if a.described else "no"} |' for a in d.judgement.alternatives]
        out.append('')
    out += [f'**Cause: {", ".join(effect_title(c) for c in d.causes) or "none"}**'
            + (f' (`{"`, `".join(d.causes)}`)' if d.causes else ''), '']
    if d.judgement is not None and d.described and d.judgement.notes:
        out += ['Findings that failed without deciding the verdict (each its own check; a '
                '"none" beside them is no all-clear):', '', '| finding | value | threshold |',
                '|---|---|---|']
        out += [f'| {f.text} | {_number(f.value)} | {_number(f.threshold)} |'
                for f in d.judgement.notes]
        out.append('')
    if d.structure:
        out.append(f'- Baseline structure the data call for (not a cause): '
                   f'{", ".join(f"`{s}`" for s in d.structure)}.')
    for choice, others in d.rivals.items():
        rivals = ', '.join(f'{effect_title(e)} (`{e}`)' for e in others)
        out.append(f'- Cannot be told apart from {effect_title(choice)} in these data: '
                   f'{rivals}; {_missing(d)}.')
    if d.causes:
        for effect, size in d.sizes().items():
            name = d.plant.effect_parameters(effect)[0].name
            low, high = doc['parameters'][name]['ci95']
            out.append(f'- {effect_title(effect)}: {size:.4g} {doc["parameters"][name]["unit"]}'
                       f', 95 % interval {_number(low)} to {_number(high)}. '
                       f'{EFFECTS[effect].physics}.')
    elif d.described:
        out.append('No effect of the library improves the validated prediction significantly: '
                   'the baseline with its re-estimated parameters explains the data as well '
                   'as any extension.')
    if d.unidentifiable:
        out += ['', '## What these signals cannot identify', '']
        out.extend(f'- {", ".join(f"{effect_title(e)} (`{e}`)" for e in effects)}: {why}.'
                   for why, effects in by_reason(d.unidentifiable).items())
        out += ['', 'Whatever these effects would explain, the unmeasured load explains as '
                'well: the verdict does not choose between them. Each is still fitted on top '
                'of what is named, and listed beside it above when it predicts the held-out '
                'windows as well.']
    if d.limits:
        out += ['', '## What these data could miss: detection limits', '',
                'Each effect left out, put into this record at growing sizes: its prediction '
                "changes the model by so much, less what the model's own parameters take up, "
                "and the selection's rules judge whether that change would have been named "
                'against the residuals this record leaves (a second-order motor loop competing, '
                'as in the selection). The limit is the weakest size from which every stronger '
                'one tried is named.', '',
                '| effect | limit | sizes tried (named marked *) |', '|---|---|---|']
        for effect, limit in d.limits.items():
            unit = '' if limit.unit in ('', '-') else f' {limit.unit}'
            value = ('not stated' if not limit.stated else 'none tried' if limit.limit is None
                     else f'{limit.limit:.3g}{unit}{" or weaker" if limit.below_range else ""}')
            tried = ', '.join(f'{size:.3g}{"*" if named else ""}'
                              for size, named in zip(limit.sizes, limit.named, strict=True))
            out.append(f'| {effect_title(effect)} | {value} | {tried} |')
        out.append('')
        out.extend(f'- {limit.sentence()}.' for limit in d.limits.values())
    out += ['', '## How the model was compared', '',
            f'Each of {d.windows.span.count} windows starts from the measured state, is '
            f'simulated from the measured input for a burn-in of {data["burn_in"]:g} s, then '
            f'scored over a horizon of {data["horizon"]:g} s; every third window '
            f'({data["validation_windows"]}) is held out for validation, the others '
            f'({data["estimation_windows"]}) estimate. Fit = 100 (1 - |y - y_hat| / '
            "|y - mean(y)|) [%] over the validation windows, as MATLAB's `compare`. An effect "
            f'is named when its validated cost falls by at least {MIN_GAIN:.0%}, the AIC on '
            'the validation windows (score) is negative and the t-test across the validation '
            f'windows gives p < {ALPHA:g}.', '',
            '## Validated fits [%]', '', '| model | ' + ' | '.join(d.plant.outputs) + ' |',
            '|---|' + '---|' * len(d.plant.outputs)]
    for name, fits in doc['fits'].items():
        out.append(f'| {name} | ' + ' | '.join(
            '-' if fits.get(o) is None else f'{fits[o]:.2f}' for o in d.plant.outputs) + ' |')
    out += ['', '![predictions](predictions.png)', '', '## Parameters of the extended model', '',
            '| parameter | value | 95 % interval | start | unit |', '|---|---|---|---|---|']
    for name, row in doc['parameters'].items():
        low, high = row['ci95']
        start = '-' if row['nominal'] is None else f'{row["nominal"]:.4g}'
        flag = ' (at a bound)' if row['at_bound'] else ''
        out.append(f'| {name} | {row["value"]:.4g}{flag} | {_number(low)} to {_number(high)} | '
                   f'{start} | {row["unit"]} |')
    out += ['', '## Ranking of the effects', '']
    for k, step in enumerate(doc['steps']):
        base = ' + '.join(['baseline', *d.causes[:k]])
        out += [f'Step {k + 1}, each effect on top of {base}:', '',
                '| effect | validated position fit [%] | cost ratio | score | p | size | '
                'how |', '|---|---|---|---|---|---|---|']
        for row in step:
            fit = '-' if row['fit'] is None else f'{row["fit"]:.2f}'
            how = 'joint fit' if row['jointly_fitted'] else 'size grid'
            mark = ' **significant**' if row['significant'] else ''
            out.append(f'| {row["effect"]}{mark} | {fit} | {row["cost_ratio"]:.3f} | '
                       f'{row["score"]:+.1f} | {row["p_value"]:.1e} | {row["size"]:.4g} '
                       f'{row["unit"]} | {how} |')
        out.append('')
    out += ['![ranking](ranking.png)', '', '## Residual tests (validation windows)', '',
            '| model | test | lags outside the 99 % band | passed |', '|---|---|---|---|']
    for name, test in d.tests.items():
        model = name.split('_')[0]
        out.append(f'| {model} | {test.name} | {test.outside:.0%} | '
                   f'{"yes" if test.passed else "no"} |')
    out += ['', 'A windowed simulation error accumulates along its window, so its '
            'autocorrelation is never white; the cross-correlation with the input says whether '
            'input-driven dynamics are missing.', '', '![residual tests](residual_tests.png)',
            '', '## What the baseline gets wrong: signatures', '',
            "Each signature bins the baseline's residuals (all windows) against the feature of "
            'one cause. They overlap (friction, for one, also changes the pressure where it is '
            'low and changing), so they show where the model is wrong; the validated fits '
            'above, not the signatures, name the cause.', '',
            '| signature | points to | statistic (t) | how |', '|---|---|---|---|']
    for signature in d.signatures:
        out.append(f'| {signature.title} | {signature.effect} | {signature.statistic:+.1f} | '
                   f'{signature.description} |')
    out += ['', '![signatures](signatures.png)', '']
    if d.transfer is not None:
        tf = d.transfer
        out += ["## The paper's third-order transfer function", '',
                f'G(s) = num(s) / den(s), num = {_poly(tf.num)}, den = {_poly(tf.den)}; poles '
                f'{_roots(tf.poles())} rad/s, zeros {_roots(tf.zeros())} rad/s, velocity gain '
                f'{tf.velocity_gain:.4g} (m/s per input unit), continuous by {tf.method}; '
                f'validated position fit {d.transfer_fit:.2f} % (Sun et al. 2021 report 82.25 % '
                'for their Eq. 15 on their own rig).', '']
        out.extend(f'- Not a physical model of the HAS, whatever its fit: {why}.'
                   for why in tf.unphysical())
    out += [f'Diagnosis time: {d.elapsed:.1f} s.', '']
    return '\n'.join(out)


def _poly(coefficients: np.ndarray) -> str:
    return '[' + ', '.join(f'{c:.4g}' for c in coefficients) + ']'


def _roots(roots: np.ndarray) -> str:
    if len(roots) == 0:
        return 'none'
    return ', '.join(f'{z.real:.4g}' if abs(z.imag) < 1e-9 else f'{z.real:.4g}{z.imag:+.4g}j'
                     for z in roots)


def _plot_predictions(d: Diagnosis, path: Path) -> None:
    """One column per shown validation window, one row per output."""
    import matplotlib.pyplot as plt

    m = d.plant.measurement
    span = d.windows.validation_span
    shown = np.unique(np.linspace(0, span.count - 1, min(SHOWN_WINDOWS, span.count))
                      .round().astype(int))
    index = span.scored()
    outputs = d.plant.outputs
    fig, axes = plt.subplots(len(outputs), len(shown), figsize=(2.6 * len(shown) + 1.0,
                                                               2.2 * len(outputs)),
                             squeeze=False)
    tf_prediction = d.transfer.predict(m.input, m.position, span) \
        if d.transfer is not None else None
    for k, output in enumerate(outputs):
        unit, scale = UNITS.get(output, ('', 1.0))
        shown_range = float(np.ptp(d.nominal.measured[shown, :, k])) * scale
        for column, w in enumerate(shown):
            ax = axes[k, column]
            t = m.time[index[w]]
            ax.plot(t, d.nominal.measured[w, :, k] * scale, 'k.', ms=2, label='measured')
            ax.plot(t, d.nominal.predicted[w, :, k] * scale, color='0.6', lw=1,
                    label='nominal')
            ax.plot(t, d.baseline_validation.predicted[w, :, k] * scale, 'C0', lw=1,
                    label='baseline (refitted)')
            if d.causes:
                ax.plot(t, d.extended_validation.predicted[w, :, k] * scale, 'C3', lw=1,
                        label='extended')
            if k == 0 and tf_prediction is not None:
                ax.plot(t, tf_prediction[w] * scale, 'C2--', lw=1,
                        label="paper's 3rd-order TF")
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=6)
            _plain(ax)
            _least_span(ax, d.nominal.measured[w, :, k] * scale, LEAST_SPAN * shown_range)
            if column == 0:
                ax.set_ylabel(f'{output} [{unit}]', fontsize=7)
            if k == len(outputs) - 1:
                ax.set_xlabel('time [s]', fontsize=7)
    axes[0, 0].legend(fontsize=6, loc='best')
    fig.suptitle('validation windows: measured and predicted', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_ranking(d: Diagnosis, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 0.45 * max(len(d.ranking), 2) + 1.0))
    names = [s.effect for s in d.ranking][::-1]
    ratios = [s.ratio for s in d.ranking][::-1]
    colours = ['C3' if s.significant else '0.6' for s in d.ranking][::-1]
    ax.barh(names, ratios, color=colours)
    ax.axvline(1.0, color='k', lw=0.8)
    ax.axvline(1.0 - MIN_GAIN, color='C3', lw=0.8, ls='--', label='largest ratio named')
    ax.set_xlabel('validated cost / baseline cost [-] (red: significant)')
    _plain(ax, 'x')  # the y axis names the effects
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_tests(d: Diagnosis, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3))
    for ax, kind in zip(axes, ('auto', 'cross'), strict=True):
        for name, colour in (('baseline', 'C0'), ('extended', 'C3')):
            test = d.tests.get(f'{name}_{kind}')
            if test is None:  # a structure verdict extends no model: the baseline's alone
                continue
            ax.plot(test.lags, test.values, 'o-', ms=2, color=colour, lw=0.8, label=name)
        if f'baseline_{kind}' not in d.tests:  # a prediction that ran away: no residuals
            ax.set_title(f'no residual test: the prediction ran away ({kind})', fontsize=9)
            continue
        band = d.tests[f'baseline_{kind}'].band
        ax.axhspan(-band, band, color='0.85', label='99 % band')
        ax.set_title(d.tests[f'baseline_{kind}'].name, fontsize=9)
        ax.set_xlabel('lag [samples]')
        ax.set_ylabel('normalised correlation [-]')
        ax.grid(alpha=0.3)
        _plain(ax)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_signatures(d: Diagnosis, path: Path) -> None:
    import matplotlib.pyplot as plt

    count = len(d.signatures)
    columns = 3
    rows = max(1, math.ceil(count / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(10, 2.6 * rows), squeeze=False)
    input_name = d.plant.measurement.input_name
    for ax, signature in zip(axes.ravel(), d.signatures, strict=False):
        # The input's signature names it without its unit, which the plant's input has.
        feature = signature.feature.replace(
            '|input|', f'|{input_name}| [{INPUT_UNITS.get(input_name, "-")}]')
        x_label, x_scale = _prefixed(feature, signature.centres)
        y_label, y_scale = _prefixed(signature.residual, np.abs(signature.means)
                                     + np.nan_to_num(signature.errors))
        ax.errorbar(signature.centres * x_scale, signature.means * y_scale,
                    yerr=signature.errors * y_scale, fmt='o-', ms=3, lw=0.8, capsize=2)
        ax.axhline(0.0, color='k', lw=0.6)
        ax.set_title(f'{signature.effect}: t = {signature.statistic:+.1f}', fontsize=8)
        ax.set_xlabel(x_label, fontsize=7)
        ax.set_ylabel(y_label, fontsize=7)
        ax.tick_params(labelsize=6)
        if signature.id == 'small_input':
            ax.set_xscale('log')
        else:
            _plain(ax)
    for ax in axes.ravel()[count:]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plain(ax: Any, which: str = 'xy') -> None:
    """Give the numeric axes (``which``) tick labels that show the values themselves.

    No offset and no power of ten beside them: matplotlib's default draws a flat signal's
    ticks as an offset and its last digits ("+3.127", "1e-6+7.27731"); the axes here carry
    their unit in the label instead.
    """
    from matplotlib.ticker import ScalarFormatter

    for axis in (getattr(ax, f'{name}axis') for name in which):
        formatter = ScalarFormatter(useOffset=False)
        formatter.set_scientific(False)
        axis.set_major_formatter(formatter)


def _least_span(ax: Any, values: np.ndarray, span: float) -> None:
    """Widen the y axis about the values to ``span`` at least (a still window drawn flat)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0 or not span > 0.0:
        return
    low, high = ax.get_ylim()
    if high - low < span:
        middle = 0.5 * (float(np.min(finite)) + float(np.max(finite)))
        ax.set_ylim(middle - 0.5 * span, middle + 0.5 * span)


def _prefixed(label: str, values: np.ndarray) -> tuple[str, float]:
    """Give the axis label its SI unit with the prefix that puts the values in 1 to 1000.

    ``label`` ends in its unit in brackets (``'pressure residual [Pa]'``); returns the label
    with the prefixed unit (``'[kPa]'``) and the factor the values are multiplied by. A unit
    outside :data:`PREFIXED_UNITS`, or values all zero, keep the label as it is.
    """
    head, bracket, rest = label.rpartition('[')
    unit = rest[:-1] if bracket and rest.endswith(']') else ''
    finite = np.abs(values[np.isfinite(values)])
    if unit not in PREFIXED_UNITS or finite.size == 0 or not np.max(finite) > 0.0:
        return label, 1.0
    power = math.floor(math.log10(float(np.max(finite))) / 3.0)
    power = min(max(power, min(PREFIXES)), max(PREFIXES))
    if unit == 's':  # seconds are not taken to kiloseconds
        power = min(power, 0)
    return f'{head}[{PREFIXES[power]}{unit}]', 1000.0 ** -power
