"""Fitting a plant's parameters to measured windows, with confidence intervals.

The residual of a window is the measured output minus the predicted one, times the output's
weight (the diagnosis makes each output's robust residual RMS 1 under the baseline, so that
position [m], pressure [Pa] and motor speed [rad/s] count alike); the cost is the mean robust
loss of the residuals (:func:`robust_loss`, soft L1). Parameters are searched in scaled
coordinates (log of the value over its start for positive ones) by
``scipy.optimize.least_squares`` (trust region reflective, bounds), with a forward-difference
Jacobian whose perturbed candidates are all simulated in one call of the plant. A parameter
with a prior (a nominal value and its stated uncertainty) adds a residual pulling it towards
its nominal value, weighed as one window of data (maximum a posteriori).

Confidence intervals come from the Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` at the
optimum (``sigma`` the residuals' robust standard deviation), inflated by ``N / N_eff``: the
residuals of a window are correlated along it (an error accumulates), and
:func:`~exo_has_sim.diagnosis.compare.effective_samples` counts how many independent samples
they are worth. Intervals of log-scale parameters are symmetric in the log:
``value exp(+-1.96 s)``. They do not include the error of the windows' initial states, which
come from noisy measurements.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from exo_has_sim.diagnosis.compare import Span, effective_samples, fit_percent
from exo_has_sim.diagnosis.plants import Parameter, WindowedModel
from exo_has_sim.errors import DiagnosisError, FitError, SimulationError

FloatArray = NDArray[np.float64]

#: Step of the forward-difference Jacobian in search coordinates (1 % for log parameters).
JACOBIAN_STEP = 0.01
#: Scale of the robust loss, in weighted residual units (1 is the baseline's robust RMS).
LOSS_SCALE = 2.0
#: Two-sided 95 % quantile of the normal distribution.
Z95 = 1.959963984540054
#: Weighted residual (in units of an output's spread) at which a prediction counts as run
#: away from the record; a diverged simulation counts as this much.
RUNAWAY = 1e3


@dataclass(frozen=True)
class Evaluation:
    """Predictions of one candidate over a set of windows.

    Attributes
    ----------
    predicted, measured : FloatArray
        Outputs, shape (windows, horizon, outputs).
    weights : FloatArray
        Weight of each output (residual units per output unit).

    """

    predicted: FloatArray
    measured: FloatArray
    weights: FloatArray

    @property
    def residuals(self) -> FloatArray:
        """Weighted residuals (measured - predicted), shape (windows, horizon, outputs)."""
        return (self.measured - self.predicted) * self.weights

    @property
    def cost(self) -> float:
        """Mean robust loss of the weighted residuals (:func:`robust_loss`)."""
        return float(np.mean(robust_loss(self.residuals)))

    def window_costs(self) -> FloatArray:
        """Mean robust loss of each window, shape (windows,)."""
        return np.asarray(np.mean(robust_loss(self.residuals), axis=(1, 2)), dtype=float)

    def window_output_costs(self) -> FloatArray:
        """Mean robust loss of each window and output, shape (windows, outputs)."""
        return np.asarray(np.mean(robust_loss(self.residuals), axis=1), dtype=float)

    def output_costs(self) -> FloatArray:
        """Mean robust loss of each output's weighted residuals."""
        return np.asarray(np.mean(robust_loss(self.residuals), axis=(0, 1)), dtype=float)

    def fit(self, output: int = 0) -> float:
        """MATLAB fit [%] of one output over these windows."""
        return fit_percent(self.measured[..., output], self.predicted[..., output])


class FitBudget(TypedDict, total=False):
    """Keyword arguments of :func:`fit_parameters` that bound its effort."""

    max_iterations: int
    tolerance: float


@dataclass(frozen=True)
class Fit:
    """Fitted parameters with their confidence intervals.

    Attributes
    ----------
    values : dict[str, float]
        Every parameter of the candidate (fitted and fixed).
    free : tuple[Parameter, ...]
        The fitted ones.
    interval : dict[str, tuple[float, float]]
        95 % confidence interval of each fitted parameter.
    cost : float
        Mean robust loss of the weighted residuals on the estimation windows (priors left
        out).
    evaluations : int
        Candidates simulated.
    converged : bool
        Whether the optimiser met its tolerance (not its evaluation budget).
    at_bound : tuple[str, ...]
        Fitted parameters that ended on a bound.
    residual : FloatArray or None
        Weighted estimation residuals at the optimum, flat (priors left out).
    jacobian : FloatArray or None
        Their derivative by the search coordinates of ``free``, shape (residuals, free).

    """

    values: dict[str, float]
    free: tuple[Parameter, ...]
    interval: dict[str, tuple[float, float]] = field(default_factory=dict)
    cost: float = math.nan
    evaluations: int = 0
    converged: bool = True
    at_bound: tuple[str, ...] = ()
    residual: FloatArray | None = field(default=None, repr=False)
    jacobian: FloatArray | None = field(default=None, repr=False)


def robust_loss(residuals: FloatArray, scale: float = LOSS_SCALE) -> FloatArray:
    """Soft-L1 loss ``2 c^2 (sqrt(1 + (r / c)^2) - 1)``: r^2 for small r, 2 c |r| for large.

    The HAS's compact valve makes the model's pressure jump by up to a megapascal when the
    motor speed passes zero and the spool dips towards free mode for a millisecond: where
    exactly depends on the speed to a fraction of a rad/s, so model and data can disagree by
    far more than the noise at a few samples, for any parameters. A quadratic cost would let
    those few samples steer the fit; this loss counts them linearly.
    """
    z = np.asarray(residuals, dtype=float) / scale
    return np.asarray(2.0 * scale ** 2 * (np.sqrt(1.0 + z * z) - 1.0), dtype=float)


def robust_rms(residuals: FloatArray) -> float:
    """Robust standard deviation, 1.4826 times the median absolute deviation."""
    r = np.asarray(residuals, dtype=float).ravel()
    r = r[np.isfinite(r)]
    return float(1.4826 * np.median(np.abs(r - np.median(r)))) if r.size else math.nan


def output_weights(plant: WindowedModel) -> FloatArray:
    """1 / standard deviation over the record of each output of a plant."""
    spread = [float(np.std(plant.measurement.signal(name))) for name in plant.outputs]
    for name, value in zip(plant.outputs, spread, strict=True):
        if not value > 0.0:
            level = float(plant.measurement.signal(name)[0])
            msg = (f'{name} is {level:g} throughout the record: nothing to compare (leave the '
                   'column out if it was not measured)')
            raise DiagnosisError(msg)
    return 1.0 / np.asarray(spread)


def evaluate(plant: WindowedModel, candidates: Sequence[Mapping[str, float]], span: Span,
             weights: FloatArray,
             linearised_at: Mapping[str, float] | None = None) -> list[Evaluation]:
    """Simulate candidates over windows (one plant call) and pair them with the data.

    A candidate whose simulation diverges gets infinite predictions (an infinite cost).
    ``linearised_at``: the candidates, near this one (a Jacobian's steps), are predicted
    linearised at it where the plant projects part of its prediction out of the data
    (:meth:`WindowedModel.predict`).
    """
    measured = plant.measured(span)
    try:
        predicted = plant.predict(candidates, span, linearised_at)
    except SimulationError:
        if len(candidates) == 1:
            predicted = np.full((1, *measured.shape), np.inf)
        else:  # find the culprits one by one
            predicted = np.stack([evaluate(plant, [c], span, weights, linearised_at)[0]
                                  .predicted for c in candidates])
    return [Evaluation(p, measured, weights) for p in predicted]


def fit_parameters(plant: WindowedModel, free: Sequence[Parameter], fixed: Mapping[str, float],
                   span: Span, weights: FloatArray,
                   initial: Mapping[str, float] | None = None, max_iterations: int = 12,
                   tolerance: float = 3e-3) -> Fit:
    """Fit the ``free`` parameters (the others held at ``fixed``) on the given windows.

    Parameters
    ----------
    plant : WindowedModel
        The model.
    free : Sequence[Parameter]
        Parameters to fit.
    fixed : Mapping[str, float]
        Values of every other parameter of the candidate.
    span : Span
        The estimation windows.
    weights : FloatArray
        Output weights (:func:`output_weights`).
    initial : Mapping[str, float] or None
        Starting values (default each parameter's ``start``), clipped into the bounds.
    max_iterations : int
        Jacobian evaluations allowed.
    tolerance : float
        Relative cost change at which the search stops.

    Raises
    ------
    FitError
        If the starting point cannot be simulated.

    """
    free = tuple(free)
    if not free:
        evaluation = evaluate(plant, [dict(fixed)], span, weights)[0]
        return Fit(dict(fixed), (), {}, evaluation.cost, 1)
    lower = np.array([p.search_bounds()[0] for p in free])
    upper = np.array([p.search_bounds()[1] for p in free])
    start_values = {p.name: p.start for p in free} | dict(initial or {})
    z0 = np.array([p.to_search(min(max(start_values[p.name], p.lower), p.upper))
                   for p in free])
    z0 = np.clip(z0, lower + 1e-9, upper - 1e-9)
    cache: dict[bytes, FloatArray] = {}
    jacobians: dict[bytes, FloatArray] = {}
    count = [0]
    data_size = span.count * span.horizon * len(weights)
    # A parameter's prior (Parameter.prior) enters as one more residual z / sigma, repeated
    # once per sample of a window: the residuals of a window are correlated along it, so a
    # window, not a sample, is an independent unit of evidence, and the prior then weighs as
    # one window's worth of data does. Repeated rather than scaled so that each copy stays in
    # the quadratic part of the robust loss.
    with_prior = [i for i, p in enumerate(free) if p.prior is not None]
    prior_sigma = np.array([free[i].prior for i in with_prior], dtype=float)

    def prior_residuals(z: FloatArray) -> FloatArray:
        return np.repeat(z[with_prior] / prior_sigma, span.horizon)

    def candidate(z: FloatArray) -> dict[str, float]:
        values = dict(fixed)
        for p, zi in zip(free, z, strict=True):
            values[p.name] = p.from_search(float(zi))
        return values

    def residual_batch(points: Sequence[FloatArray],
                       around: FloatArray | None = None) -> list[FloatArray]:
        count[0] += len(points)
        found = evaluate(plant, [candidate(z) for z in points], span, weights,
                         None if around is None else candidate(around))
        out = []
        if len(cache) > 2 * len(free) + 4:  # only the latest point and its Jacobian matter
            cache.clear()
        for z, evaluation in zip(points, found, strict=True):
            r = evaluation.residuals.ravel()
            r = np.where(np.isfinite(r), r, RUNAWAY)  # a diverged candidate: a large residual
            if with_prior:
                r = np.concatenate((r, prior_residuals(z)))
            if around is None:  # a linearised residual is no value of the cost function
                cache[z.tobytes()] = r
            out.append(r)
        return out

    def fun(z: FloatArray) -> FloatArray:
        key = z.tobytes()
        return cache[key] if key in cache else residual_batch([z])[0]

    def jac(z: FloatArray) -> FloatArray:
        steps = []
        for i in range(len(z)):
            step = JACOBIAN_STEP if z[i] + JACOBIAN_STEP <= upper[i] else -JACOBIAN_STEP
            steps.append(step)
        points = [z + np.eye(len(z))[i] * steps[i] for i in range(len(z))]
        if plant.linearises:
            # Points so near are predicted linearised at their base (WindowedModel.predict), and
            # differenced from the base predicted so too.
            base, *rows = residual_batch([z, *points], around=z)
        else:
            base, rows = fun(z), residual_batch(points)
        columns = [(r - base) / s for r, s in zip(rows, steps, strict=True)]
        jacobians.clear()  # the last one is kept for the intervals
        jacobians[z.tobytes()] = np.column_stack(columns)
        return jacobians[z.tobytes()]

    r0 = fun(z0)[:data_size]
    if not np.all(np.abs(r0) < RUNAWAY):
        msg = f'the starting point of the fit cannot be simulated: {candidate(z0)}'
        raise FitError(msg)
    result = least_squares(fun, z0, jac=jac, bounds=(lower, upper), method='trf',
                           x_scale=1.0, ftol=tolerance, xtol=tolerance, gtol=1e-8,
                           max_nfev=max_iterations * 2, loss='soft_l1', f_scale=LOSS_SCALE)
    z = np.asarray(result.x, dtype=float)
    values = candidate(z)
    residual = fun(z)[:data_size]
    jacobian = (jacobians[z.tobytes()] if z.tobytes() in jacobians else jac(z))[:data_size]
    shape = (span.count, span.horizon, len(weights))
    interval = confidence_intervals(free, z, jacobian, residual, shape,
                                    span.horizon * _prior_information(free))
    width = upper - lower
    at_bound = tuple(p.name for p, zi, lo, hi, w in zip(free, z, lower, upper, width,
                                                        strict=True)
                     if min(zi - lo, hi - zi) < 1e-3 * w)
    return Fit(values, free, interval, float(np.mean(robust_loss(residual))), count[0],
               bool(result.status > 0), at_bound, residual, jacobian)


def _prior_information(free: Sequence[Parameter]) -> FloatArray:
    """Return each parameter's prior information per residual row, ``1 / prior^2`` (or 0)."""
    return np.array([0.0 if p.prior is None else 1.0 / p.prior ** 2 for p in free])


def confidence_intervals(free: Sequence[Parameter], z: FloatArray, jacobian: FloatArray,
                         residual: FloatArray, shape: tuple[int, int, int],
                         prior: FloatArray | None = None) -> dict[str, tuple[float, float]]:
    """95 % intervals from ``sigma^2 (J^T J + P)^-1`` inflated for correlated residuals.

    ``residual`` is the flat weighted residual vector of shape (windows, horizon, outputs);
    ``prior`` the information of each parameter's prior (the diagonal P, in the search
    coordinate: the rows the fit adds, ``horizon / prior^2``), so that a parameter known from
    its prior where the data say little keeps the prior's interval; a parameter neither
    determines (a singular direction) gets an unbounded interval.
    """
    n, p = jacobian.shape
    if n <= p:
        return {q.name: (-math.inf, math.inf) for q in free}
    sigma2 = robust_rms(residual) ** 2 * n / (n - p)
    by_output = residual.reshape(shape)
    n_eff = min(effective_samples(by_output[..., k]) for k in range(shape[2]))
    inflation = max(1.0, shape[0] * shape[1] / n_eff)
    information = jacobian.T @ jacobian
    if prior is not None:
        information = information + np.diag(prior)
    covariance = np.linalg.pinv(information, rcond=1e-12) * sigma2 * inflation
    out = {}
    for i, q in enumerate(free):
        sd = math.sqrt(max(float(covariance[i, i]), 0.0))
        if not math.isfinite(sd) or information[i, i] == 0.0:
            out[q.name] = (-math.inf, math.inf)
            continue
        low, high = z[i] - Z95 * sd, z[i] + Z95 * sd
        out[q.name] = (q.from_search(min(low, 700.0)), q.from_search(min(high, 700.0)))
    return out
