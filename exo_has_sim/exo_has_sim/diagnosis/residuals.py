"""Residual analysis: whiteness and input cross-correlation tests, and effect signatures.

Tests as MATLAB's ``resid``: the normalised autocorrelation of the residuals at lags 1 to
:data:`MAX_LAG` and their cross-correlation with the input at lags -MAX_LAG to MAX_LAG, with the
99 % band ``+-2.58 / sqrt(N)`` of white residuals independent of the input; a test passes when
the portmanteau statistic over all its lags is within its 99 % quantile. Correlations are
computed within windows (each window's residual sequence is separate) and pooled. A windowed
simulation error accumulates along its window, so its autocorrelation is never white; the
test that says whether the model misses input-driven dynamics is the cross-correlation.

Signatures. Each candidate cause leaves a pattern in the baseline's residuals; each signature
bins a residual against the feature of one cause and condenses the pattern into a statistic in
units of its standard error (a t value), so the report can show which patterns stand out.
Residual "rates" are the increase of a window's residual over one sample divided by the
period, i.e. a velocity (position) or pressure-rate (pressure) error: the accumulated error
itself mixes everything that happened since the window began.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Largest lag of the correlation tests [samples].
MAX_LAG = 25
#: Two-sided 99 % quantile of the normal distribution (MATLAB resid's band).
Z99 = 2.5758293035489004


@dataclass(frozen=True)
class CorrelationTest:
    """A correlation test of residuals.

    Attributes
    ----------
    lags : IntArray
        Lags [samples].
    values : FloatArray
        Normalised correlation at each lag.
    band : float
        Half-width of the 99 % band of the null hypothesis.
    name : str
        What is correlated.

    """

    lags: IntArray
    values: FloatArray
    band: float
    name: str

    @property
    def outside(self) -> float:
        """Fraction of lags outside the band."""
        return float(np.mean(np.abs(self.values) > self.band)) if len(self.values) else 0.0

    @property
    def p_value(self) -> float:
        """Return p of the portmanteau (Box-Pierce) statistic ``N sum r_k^2``.

        Under the null hypothesis it is chi-square with one degree of freedom per lag.
        """
        samples = (Z99 / self.band) ** 2
        return float(chi2.sf(samples * float(np.sum(self.values ** 2)), len(self.values)))

    @property
    def passed(self) -> bool:
        """Whether the portmanteau test accepts the null hypothesis at the 1 % level.

        Counting lags outside the band would not do: every one of 25 lags within a 99 % band
        fails a fifth of white sequences, and one lag far outside is a clear failure.
        """
        return self.p_value > 0.01


def _centred(windows: FloatArray) -> FloatArray:
    w = np.asarray(windows, dtype=float)
    return np.asarray(w - np.mean(w, axis=1, keepdims=True), dtype=float)


def autocorrelation(residuals: FloatArray, max_lag: int = MAX_LAG) -> CorrelationTest:
    """Whiteness test of residuals of shape (windows, samples), lags 1 to ``max_lag``."""
    e = _centred(residuals)
    lags = np.arange(1, min(max_lag, e.shape[1] - 1) + 1)
    energy = float(np.sum(e * e))
    values = np.array([np.sum(e[:, k:] * e[:, :-k]) / energy if energy else 0.0
                       for k in lags])
    return CorrelationTest(lags, values, Z99 / math.sqrt(e.size), 'residual autocorrelation')


def cross_correlation(residuals: FloatArray, inputs: FloatArray,
                      max_lag: int = MAX_LAG) -> CorrelationTest:
    """Cross-correlation of residuals with the input, lags -max_lag to max_lag.

    Lag k > 0 pairs the residual with the input k samples earlier (a delay shows there).
    """
    e, u = _centred(residuals), _centred(inputs)
    limit = min(max_lag, e.shape[1] - 1)
    lags = np.arange(-limit, limit + 1)
    scale = math.sqrt(float(np.sum(e * e)) * float(np.sum(u * u)))
    values = []
    for k in lags:
        if k >= 0:
            total = np.sum(e[:, k:] * u[:, :e.shape[1] - k])
        else:
            total = np.sum(e[:, :k] * u[:, -k:])
        values.append(total / scale if scale else 0.0)
    return CorrelationTest(lags, np.array(values), Z99 / math.sqrt(e.size),
                           'residual-input cross-correlation')


@dataclass(frozen=True)
class Signature:
    """A residual binned against the feature of a candidate cause.

    Attributes
    ----------
    id : str
        Identifier.
    title : str
        What is plotted.
    effect : str
        The effect whose signature it is.
    feature : str
        Name and unit of the x axis.
    residual : str
        Name and unit of the y axis.
    centres, means, errors : FloatArray
        Bin centres, mean residual per bin and its standard error.
    statistic : float
        The pattern's strength in units of its standard error (t value).
    description : str
        How the statistic is formed.

    """

    id: str
    title: str
    effect: str
    feature: str
    residual: str
    centres: FloatArray
    means: FloatArray
    errors: FloatArray
    statistic: float
    description: str


def binned(feature: FloatArray, values: FloatArray,
           edges: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean and standard error of ``values`` in bins of ``feature`` (empty bins are NaN)."""
    centres = 0.5 * (edges[1:] + edges[:-1])
    means = np.full(len(centres), np.nan)
    errors = np.full(len(centres), np.nan)
    index = np.digitize(feature, edges) - 1
    for i in range(len(centres)):
        chosen = values[index == i]
        if len(chosen) >= 2:
            means[i] = float(np.mean(chosen))
            errors[i] = float(np.std(chosen, ddof=1) / math.sqrt(len(chosen)))
    return centres, means, errors


def _t_difference(first: FloatArray, second: FloatArray) -> float:
    """Welch t of mean(first) - mean(second)."""
    if len(first) < 2 or len(second) < 2:
        return 0.0
    se = math.sqrt(float(np.var(first, ddof=1)) / len(first)
                   + float(np.var(second, ddof=1)) / len(second))
    return float((np.mean(first) - np.mean(second)) / se) if se else 0.0


def _t_mean(values: FloatArray) -> float:
    """T of the mean of values against zero."""
    if len(values) < 2:
        return 0.0
    se = float(np.std(values, ddof=1)) / math.sqrt(len(values))
    return float(np.mean(values)) / se if se else 0.0


def _t_correlation(x: FloatArray, y: FloatArray) -> float:
    """T value of the Pearson correlation of x and y."""
    if len(x) < 3 or np.std(x) == 0.0 or np.std(y) == 0.0:
        return 0.0
    r = float(np.corrcoef(x, y)[0, 1])
    r = max(min(r, 0.999999), -0.999999)
    return r * math.sqrt((len(x) - 2) / (1.0 - r * r))


def _quantile_edges(values: FloatArray, count: int) -> FloatArray:
    edges = np.unique(np.quantile(values, np.linspace(0.0, 1.0, count + 1)))
    if len(edges) < 2:
        edges = np.array([float(np.min(values)) - 0.5, float(np.max(values)) + 0.5])
    edges[-1] += 1e-12 * max(1.0, abs(float(edges[-1])))
    return np.asarray(edges, dtype=float)


def signatures(features: Mapping[str, FloatArray], rates: Mapping[str, FloatArray],
               residuals: Mapping[str, FloatArray], period: float,
               relief_pressure: float | None = None, bins: int = 12) -> list[Signature]:
    """Compute the signatures that the available signals allow.

    Parameters
    ----------
    features : Mapping[str, FloatArray]
        At the scored samples, flat: ``velocity`` [m/s], ``input`` (command [rad/s] or force
        [N]), ``input_rate`` (its change per second), ``since_reversal`` [s] (time since the
        velocity changed sign), and when measured ``pressure`` [Pa] and ``pressure_rate``
        [Pa/s].
    rates : Mapping[str, FloatArray]
        Residual rates at the same samples: ``position`` [m/s] and, when measured,
        ``pressure`` [Pa/s] and ``motor_speed`` [rad/s^2].
    residuals : Mapping[str, FloatArray]
        Residuals at the same samples: ``position`` [m], ``pressure`` [Pa].
    period : float
        Sample period [s].
    relief_pressure : float or None
        Setting of the safety valve [Pa] (HAS only).
    bins : int
        Bins per plot.

    """
    out: list[Signature] = []
    v = features['velocity']
    u = features['input']
    flow = rates['position']
    force_residual = residuals.get('pressure', residuals['position'])
    force_name = 'pressure residual [Pa]' if 'pressure' in residuals else 'position residual [m]'
    speed_edges = _quantile_edges(v, bins)
    centres, means, errors = binned(v, force_residual, speed_edges)
    out.append(Signature(
        'velocity_sign', 'residual against velocity', 'coulomb_friction', 'velocity [m/s]',
        force_name, centres, means, errors,
        _t_difference(force_residual[v > 0], force_residual[v < 0]),
        'Welch t of mean residual when extending minus retracting (friction: a step at 0)'))
    since = features['since_reversal']
    near = since < 0.05
    centres, means, errors = binned(since, np.abs(flow), np.linspace(0.0, 0.5, bins + 1))
    out.append(Signature(
        'reversals', 'velocity error after a direction reversal', 'coulomb_friction',
        'time since the velocity changed sign [s]', '|position residual rate| [m/s]',
        centres, means, errors, _t_difference(np.abs(flow[near]), np.abs(flow[~near])),
        'Welch t of |velocity error| within 50 ms of a reversal minus elsewhere'))
    magnitude = np.abs(u)
    top = float(np.max(magnitude)) if len(magnitude) else 0.0
    if top > 0.0:  # an input at zero throughout has no size to bin by
        edges = np.geomspace(top * 1e-3, top * (1 + 1e-9), bins + 1)
        signed = flow * np.sign(u)
        centres, means, errors = binned(magnitude, signed, edges)
        small = magnitude < np.quantile(magnitude, 0.5)
        out.append(Signature(
            'small_input', 'velocity error along the input against its size', 'pump_deadzone',
            '|input|', 'position residual rate x sign(input) [m/s]', centres, means, errors,
            -_t_mean(signed),
            'minus the t of the mean velocity error along the input (a dead zone: the plant '
            "moves slower than the model in the input's direction, most for small inputs); "
            f'{int(np.sum(small))} samples below the median input'))
    rate = features['input_rate']
    lag_values = []
    target = rates.get('motor_speed', flow)
    for lag in range(11):
        shifted = np.roll(rate, lag)
        lag_values.append(_t_correlation(shifted[lag:], target[lag:]) if lag < len(rate)
                          else 0.0)
    lags = np.arange(11, dtype=float) * period
    best = int(np.argmax(np.abs(lag_values)))
    out.append(Signature(
        'lagged_input', "residual rate correlated with the input's rate, by lag",
        'transport_delay', 'lag [s]',
        't of the correlation with the input rate [-]', lags, np.array(lag_values),
        np.ones(len(lags)), float(abs(lag_values[best])),
        f'largest |t| of the correlation, at lag {lags[best] * 1e3:.0f} ms (a delay: '
        "the model runs ahead of the plant by the input's rate times the delay)"))
    if 'pressure' in features:
        p = features['pressure']
        edges = _quantile_edges(p, bins)
        centres, means, errors = binned(p, flow, edges)
        out.append(Signature(
            'pressure_level', 'velocity error against pressure', 'quadratic_leakage',
            'pressure [Pa]', 'position residual rate [m/s]', centres, means, errors,
            -_t_correlation(p * np.abs(p), flow),
            'minus the t of the correlation of the velocity error with p|p| (an extra '
            'leakage growing with pressure: the plant is slower the higher the pressure)'))
        if relief_pressure:
            ratio = p / relief_pressure
            edges = np.linspace(min(0.0, float(np.min(ratio))), max(1.0, float(np.max(ratio))),
                                bins + 1)
            centres, means, errors = binned(ratio, flow, edges)
            high = p > 0.5 * relief_pressure
            out.append(Signature(
                'near_relief', 'velocity error against pressure over the relief setting',
                'relief_valve', 'p / p_relief [-]', 'position residual rate [m/s]', centres,
                means, errors, -_t_difference(flow[high], flow[~high]),
                'minus the Welch t of the velocity error above half the relief setting '
                'minus below (a cracked valve loses flow only above its crack pressure)'))
        if 'pressure' in rates:
            low = p < np.quantile(p, 0.3)
            dp = features['pressure_rate']
            edges = _quantile_edges(dp[low], bins) if np.any(low) else _quantile_edges(dp, bins)
            centres, means, errors = binned(dp[low], rates['pressure'][low], edges)
            out.append(Signature(
                'low_pressure_compliance', 'pressure-rate error against the pressure rate, '
                'lowest 30 % of pressures', 'entrained_air', 'measured dp/dt [Pa/s]',
                'pressure residual rate [Pa/s]', centres, means, errors,
                -_t_correlation(dp[low], rates['pressure'][low]),
                'minus the t of the correlation of the pressure-rate error with dp/dt at low '
                'pressure (air: the plant is softer there than the model, so its pressure '
                'changes less)'))
    return out
