"""The pump's flow gain by direction, read two ways, and when the reading cannot be trusted.

A circuit shows in how fast the cylinder moves per unit of pump flow each way: the paper's pump
fills and empties the rodless chamber both ways (a ratio of 1, retracting over extending); a
pump that feeds the rod side to retract moves it A_A/A_B times as fast that way. The ratio is
read by a regression of the rodless chamber's flow balance with the losses fitted beside it
(:func:`flow_gains`), and checked against the plainest reading a user can make by hand, a
ratio of medians over steady samples (:func:`direct_ratio`); :func:`regression_doubt` says
when the regression cannot be trusted. :func:`~exo_has_sim.diagnosis.evidence.direction_gain`
turns them into a finding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from exo_has_sim import model
from exo_has_sim.diagnosis.fitting import Z95, FloatArray

#: Least speed of a cylinder sample in the direct look at the flow gains, as a share of the
#: 95th percentile of its speed: a rod that barely moves gives a ratio of noise.
DIRECT_VELOCITY_SHARE = 0.1
#: Resamples of the windows for the spread of the direct ratio; its seed, for a diagnosis that
#: says the same twice.
RESAMPLES = 400
RESAMPLE_SEED = 37
#: Share of the regression's resamples whose gain is not positive beyond which its ratio is
#: not determined.
UNDEFINED_SHARE = 0.025
#: Factor by which the direct look may part from the regression for a loss's sake: a loss at
#: the loaded chamber's pressure slows the direction it loads, which the direct look does not
#: take out (the third truth plant with a brake of several kN: 1.77 for a true 1.485, 19 %).
DIRECT_ALLOWANCE = 1.25
#: Largest ratio (or its inverse) of the record's flow gains by direction, retracting over
#: extending, to the circuit's own that a right structure leaves.
DIRECTION_RATIO = 1.2
#: Share of the pump speed's 95th percentile below which a sample does not count for the flow
#: gains (a pump that barely turns says little of its gain).
MOVING_SHARE = 0.15
#: Fewest samples each direction needs for the flow gain to be judged.
MIN_SAMPLES = 50


@dataclass(frozen=True)
class FlowGains:
    """The pump's flow gain by direction, from a regression of the rodless chamber's balance.

    ``A_A v = k_ext D_p n+ + k_ret D_p n- + c_ext + c_ret - sum_c (f_c(p_c) + C_c(p_c)
    dp_c/dt)`` over the samples in motion (``n+`` the pump speed where positive, else 0;
    ``n-`` likewise; ``c_ext``, ``c_ret`` a constant flow in each direction; c each chamber
    whose pressure is known): the share of the pump's flow each direction turns into the
    rodless chamber's motion, with what else the flow does fitted beside it. Each of these
    would otherwise pass for a flow gain that differs by direction: a loss ``f_c``, any
    piecewise-linear function of the pressure (a slope, and hinges at its knots), as a
    leakage that grows faster than linearly or a relief valve that cracks takes flow from the
    loaded chamber both ways (a cracked valve on the second truth plant had given 2.35); the
    constants, as a pump dead zone takes a fixed speed off each direction; the compliance
    ``C_c(p) = C_c0 + C_c1 / (p + p_atm)``, as free air in the oil is soft at low pressure
    (on the third truth plant both had given 0.74 to 0.83).

    Attributes
    ----------
    extending, retracting : float
        k_ext and k_ret [-].
    ratio : float
        k_ret / k_ext.
    error : float
        Standard error of the ratio's logarithm: the least-squares formula's, or where
        larger (windows given) the spread of the ratio over resamples of the windows.
    samples : int
        Samples used.

    """

    extending: float
    retracting: float
    ratio: float
    error: float
    samples: int


def flow_gains(velocity: FloatArray, speed: FloatArray,
               pressures: Sequence[tuple[FloatArray, FloatArray, Sequence[float]]],
               area: float, displacement: float,
               mask: NDArray[np.bool_] | None = None) -> FlowGains | None:
    """Regress the rodless chamber's flow balance by direction (:class:`FlowGains`).

    ``pressures`` holds each known chamber pressure [Pa] with its rate [Pa/s], of the
    velocity's shape, and the knots [Pa] of its loss; ``mask`` the samples that may count.

    Samples count where the pump turns (above :data:`MOVING_SHARE` of its 95th percentile),
    whichever way the cylinder then moves: keeping only those where it moves the pump's way
    would drop the samples where a loss wins over the pump, and bias the direction that loses
    most; None when either direction has fewer than :data:`MIN_SAMPLES` of them or the
    regression is singular.
    """
    v, n = velocity.ravel(), speed.ravel()
    n_floor = MOVING_SHARE * float(np.percentile(np.abs(n), 95))
    use = np.abs(n) > n_floor
    if mask is not None:
        use &= mask.ravel()
    up, down = use & (n > 0.0), use & (n < 0.0)
    if np.count_nonzero(up) < MIN_SAMPLES or np.count_nonzero(down) < MIN_SAMPLES:
        return None
    columns = [np.where(up, displacement * n, 0.0), np.where(down, displacement * n, 0.0),
               up.astype(float), -down.astype(float)]
    for pressure, rate, knots in pressures:
        p = pressure.ravel()
        columns += [-p, -rate.ravel(),
                    -rate.ravel() / (np.maximum(p, 0.0) + model.ATMOSPHERIC_PRESSURE),
                    *(-np.maximum(p - knot, 0.0) for knot in knots)]
    design = np.column_stack(columns)[use]
    target = area * v[use]
    # Columns of flows [m^3/s], pressures [Pa] and pressure rates [Pa/s] differ by 1e13:
    # scaled to unit spread, the least squares does not lose the small ones.
    scale = np.std(design, axis=0)
    scale = np.where(scale > 0.0, scale, 1.0)
    scaled = design / scale
    try:
        coef, *_ = np.linalg.lstsq(scaled, target, rcond=None)
        residual = target - scaled @ coef
        dof = max(len(target) - design.shape[1], 1)
        covariance = np.linalg.pinv(scaled.T @ scaled) * float(residual @ residual) / dof
    except np.linalg.LinAlgError:
        return None
    coef = coef / scale
    covariance = covariance / np.outer(scale, scale)
    k_ext, k_ret = float(coef[0]), float(coef[1])
    if not (k_ext > 0.0 and k_ret > 0.0):
        return None
    error = math.sqrt(max(covariance[0, 0] / k_ext ** 2 + covariance[1, 1] / k_ret ** 2
                          - 2.0 * covariance[0, 1] / (k_ext * k_ret), 0.0))
    if velocity.ndim == 2:
        rows = np.repeat(np.arange(velocity.shape[0]), velocity.shape[1])[use]
        error = max(error, _resampled_error(scaled, target, rows))
    return FlowGains(k_ext, k_ret, k_ret / k_ext, error, int(np.count_nonzero(use)))


def _resampled_error(design: FloatArray, target: FloatArray, rows: NDArray[np.int64]) -> float:
    """Return the standard error of the log of the regression's ratio over its windows.

    The formula's error treats every sample as independent evidence; samples of a window are
    not, and where the losses trade with the direction's gain (a loaded chamber that
    alternates with the direction) the ratio moves from window set to window set far more
    than it says. Infinite where over :data:`UNDEFINED_SHARE` of the resamples give a gain
    that is not positive: the windows then do not determine it.
    """
    present = np.unique(rows)
    if len(present) < 2:
        return 0.0
    columns = design.shape[1]
    gram = np.zeros((int(present.max()) + 1, columns, columns))
    moment = np.zeros((int(present.max()) + 1, columns))
    for row in present:
        chosen = rows == row
        gram[row] = design[chosen].T @ design[chosen]
        moment[row] = design[chosen].T @ target[chosen]
    rng = np.random.default_rng(RESAMPLE_SEED)
    logs = []
    for _ in range(RESAMPLES):
        pick = rng.choice(present, len(present))
        coef = np.linalg.lstsq(gram[pick].sum(axis=0), moment[pick].sum(axis=0), rcond=None)[0]
        logs.append(math.log(coef[1] / coef[0]) if coef[0] > 0.0 and coef[1] > 0.0
                    else math.nan)
    values = np.array(logs)
    if np.mean(np.isnan(values)) > UNDEFINED_SHARE:
        return math.inf
    return float(np.std(values[np.isfinite(values)]))


@dataclass(frozen=True)
class DirectRatio:
    """The flow gain by direction read straight off the samples, as a user can check it.

    ``median(A_A v / (D_p n))`` over the steady retracting samples over the same median over
    the steady extending ones: a sample is steady where the pump turns (above
    :data:`MOVING_SHARE` of its 95th percentile), the cylinder moves the pump's way (above
    :data:`DIRECT_VELOCITY_SHARE` of its 95th percentile) and the command has settled. It
    takes no loss out, so a loss at the loaded chamber's pressure biases it (a brake of
    several kN read 1.77 for a true 1.485); it is the yardstick that the regression of
    :func:`flow_gains` must not contradict, not a substitute for it.

    Attributes
    ----------
    ratio : float
        The ratio of medians [-].
    error : float
        Standard error of its logarithm, from resampling the windows (a window is an
        independent unit of evidence; its samples are not).
    samples : int
        Steady samples used.
    speed_floor : float
        Least pump speed of a sample [rad/s].
    velocity_floor : float
        Least cylinder speed of a sample [m/s].

    """

    ratio: float
    error: float
    samples: int
    speed_floor: float
    velocity_floor: float

    def sentence(self) -> str:
        """Say the calculation and its result."""
        low, high = (self.ratio * math.exp(s * Z95 * self.error) for s in (-1.0, 1.0))
        return (f'directly, the median of A_A v / (D_p n) retracting over extending is '
                f'{self.ratio:.2f} (95 % {low:.2f} to {high:.2f}; {self.samples} steady '
                f'samples, |n| > {self.speed_floor:.3g} rad/s, |v| > '
                f"{self.velocity_floor * 1e3:.3g} mm/s, the rod moving the pump's way)")


def direct_ratio(velocity: FloatArray, speed: FloatArray, area: float, displacement: float,
                 mask: NDArray[np.bool_] | None = None,
                 least_speed: float = 0.0) -> DirectRatio | None:
    """Read the flow gain by direction off the steady samples (:class:`DirectRatio`).

    ``velocity`` [m/s] and ``speed`` [rad/s] are of shape (windows, samples), ``mask`` the
    samples that may count, ``least_speed`` [rad/s] a floor of the pump's speed beside the
    share of its 95th percentile. None where either direction has fewer than
    :data:`MIN_SAMPLES` steady samples, or fewer than two windows hold any.
    """
    v, n = np.asarray(velocity, dtype=float), np.asarray(speed, dtype=float)
    speed_floor = max(MOVING_SHARE * float(np.percentile(np.abs(n), 95)), least_speed)
    velocity_floor = DIRECT_VELOCITY_SHARE * float(np.percentile(np.abs(v), 95))
    steady = (np.abs(n) > speed_floor) & (np.abs(v) > velocity_floor) \
        & (np.sign(v) == np.sign(n))
    if mask is not None:
        steady &= mask
    gain = np.where(steady, area * v / (displacement * np.where(n != 0.0, n, 1.0)), np.nan)
    up, down = steady & (n > 0.0), steady & (n < 0.0)
    if np.count_nonzero(up) < MIN_SAMPLES or np.count_nonzero(down) < MIN_SAMPLES:
        return None
    rows = np.flatnonzero(np.any(steady, axis=1))
    if len(rows) < 2:
        return None

    def ratio(chosen: NDArray[np.int64]) -> float:
        g, u, d = gain[chosen], up[chosen], down[chosen]
        if not (np.any(u) and np.any(d)):
            return math.nan
        return float(np.median(g[d]) / np.median(g[u]))

    value = ratio(rows)
    if not value > 0.0:
        return None
    rng = np.random.default_rng(RESAMPLE_SEED)
    resampled = np.array([ratio(rng.choice(rows, len(rows))) for _ in range(RESAMPLES)])
    logs = np.log(resampled[np.isfinite(resampled) & (resampled > 0.0)])
    error = float(np.std(logs)) if len(logs) > 1 else math.inf
    return DirectRatio(value, error, int(np.count_nonzero(up | down)), speed_floor,
                       velocity_floor)


def regression_doubt(data: FlowGains, direct: DirectRatio | None,
                     areas: float | None = None) -> str | None:
    """Say why the regression's flow gain by direction cannot be trusted, or None.

    It cannot where it gives a ratio under 1 by more than :data:`DIRECTION_RATIO`, which no
    circuit can (retracting, a pump feeds an area no larger than A_A), whatever its own
    uncertainty (0.41 +-72 % on a rig braked to a crawl; our own plant's 0.99 +-0.8 % is no
    such value); where its uncertainty leaves both
    circuits' ratios, 1 and ``areas`` (A_A/A_B), within :data:`DIRECTION_RATIO` (4577
    samples of a rig braked at 4.7 kN over a few millimetres gave 3.80 +-185 %); where it and
    the direct look (:func:`direct_ratio`) part by more than their joint uncertainty and the
    bias a loss gives the direct look (:data:`DIRECT_ALLOWANCE`). A loss outside the
    regression's family, a loaded chamber that alternates with the direction, a logged speed
    that lags: each can move one and not the other. (The two are not asked to agree on the
    verdict: a quadratic leakage on the third truth plant took the direct look to 1.10 where
    the regression read 1.38, for a true 1.46.)
    """
    if data.ratio < 1.0 / DIRECTION_RATIO:
        return (f'the regression gives {data.ratio:.2f}, under 1 by more than a right '
                f'structure leaves ({DIRECTION_RATIO:g}), which no circuit can (retracting, a '
                'pump feeds an area no larger than A_A)')
    if areas is not None and within(data.ratio, data.error, 1.0) \
            and within(data.ratio, data.error, areas):
        return (f'the regression ({data.ratio:.2f}, +-{math.exp(Z95 * data.error) - 1.0:.0%}) '
                f'leaves both 1 and A_A/A_B = {areas:.2f} possible')
    if direct is None:
        return None
    apart = abs(math.log(data.ratio / direct.ratio))
    if apart > math.log(DIRECT_ALLOWANCE) + Z95 * math.hypot(data.error, direct.error):
        return (f'the regression ({data.ratio:.2f}) and the direct look ({direct.ratio:.2f}) '
                f'part by more than their uncertainty and the {DIRECT_ALLOWANCE - 1.0:.0%} a '
                'loss may bias the direct look')
    return None


def within(ratio: float, error: float, expected: float) -> bool:
    """Say whether a ratio lies within :data:`DIRECTION_RATIO` of the expected one.

    Give or take its own uncertainty, ``error`` (a standard error of its logarithm).
    """
    return abs(math.log(ratio / expected)) <= math.log(DIRECTION_RATIO) + Z95 * error
