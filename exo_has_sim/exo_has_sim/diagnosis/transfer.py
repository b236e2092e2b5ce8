"""The paper's own identification (section 4.2): a third-order transfer function by least squares.

Sun et al. identify "a third-order system" from the speed command to the cylinder position,
with the structure of their Eq. 12 (an integrator and a second-order velocity response; Eq. 15
as identified has its slowest pole at -0.24 rad/s, almost an integrator), "by the least squares
regression method". Here: the discrete-time model with the integrator built in,

    (1 - q^-1)(1 + a1 q^-1 + a2 q^-2) x_k = (b1 q^-1 + b2 q^-2 + b3 q^-3) u_k,

i.e. an ARX model of order (2, 3, 1) of the position increments, whose coefficients are linear
in the data and found by linear least squares on the estimation windows (the zero-order-hold
image of any strictly proper third-order G(s) with a pole at 0 has this form), then refined by
nonlinear least squares on the windowed simulation error (:func:`identify_third_order`). The
continuous G(s) is recovered by the inverse of the zero-order hold (the matrix logarithm of the
sampled state-space model), and reported as num/den, poles and zeros, beside Eq. 15. The paper
identified the loop under P = 35 and removed the controller; with the command recorded, the
direct open-loop estimate from command to position is the same model without that step (an
equation-error estimate is biased by the noise the loop feeds back, which the output-error
refinement is not).

Its fit is computed as the project model's: over the same validation windows, each predicted
from the measured positions just before it (the model's initial state) and the measured
inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.linalg import expm, logm
from scipy.optimize import least_squares
from scipy.signal import ss2tf

from exo_has_sim.diagnosis.compare import Span, fit_percent
from exo_has_sim.errors import FitError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

#: Samples of past outputs and inputs the regression needs.
ORDER = 3


@dataclass(frozen=True)
class ThirdOrderModel:
    """An identified third-order model with an integrator, from input u to position x.

    Attributes
    ----------
    a : FloatArray
        ``[a1, a2]`` of the increments' autoregression.
    b : FloatArray
        ``[b1, b2, b3]`` of the input.
    period : float
        Sample period [s].
    num, den : FloatArray
        Continuous G(s) = num(s)/den(s), highest power first, den monic.
    method : str
        How G(s) relates to the discrete model (``'zoh'``: the discrete model is its
        zero-order-hold sampling).

    """

    a: FloatArray
    b: FloatArray
    period: float
    num: FloatArray
    den: FloatArray
    method: str

    def poles(self) -> ComplexArray:
        """Poles of G(s) [rad/s]."""
        return np.asarray(np.roots(self.den), dtype=complex)

    def zeros(self) -> ComplexArray:
        """Zeros of G(s) [rad/s]."""
        return np.asarray(np.roots(self.num), dtype=complex) if len(self.num) > 1 \
            else np.zeros(0, dtype=complex)

    @property
    def velocity_gain(self) -> float:
        """Steady velocity per input, lim s G(s) as s -> 0 [m/s per input unit]."""
        return float(self.num[-1] / self.den[-2]) if self.den[-2] else math.inf

    def unphysical(self) -> list[str]:
        """Say what makes G(s) no physical model of a pump-driven cylinder (none: empty).

        A HAS extends for a positive speed command, so its velocity gain is positive; the
        paper's Eq. 12 has its poles but the integrator in the left half-plane and no zeros,
        Eq. 15 its zeros in the left half-plane too (zeros beyond a quarter of the sampling
        rate, which sampling puts there, are let be). A model that fits the data with a
        negative gain or a zero or pole in the right half-plane fits by accident (a window's
        start state does much of the prediction over a short horizon), and no verdict rests
        on it.
        """
        out = []
        if not self.velocity_gain > 0.0:
            out.append(f'velocity gain {self.velocity_gain:.3g} (m/s) per unit of the command, '
                       'not positive')
        # Zeros beyond a quarter of the sampling rate are the sampling's (the inverse of the
        # zero-order hold puts them there), not the plant's.
        band = 0.5 * math.pi / self.period
        right = [z for z in self.zeros() if z.real > 0.0 and abs(z) < band]
        if right:
            out.append(f'{len(right)} zero(s) in the right half-plane (non-minimum phase): '
                       + ', '.join(f'{z.real:.3g}{z.imag:+.3g}j' for z in right))
        unstable = [z for z in self.poles() if z.real > 1e-6 * max(1.0, abs(z))]
        if unstable:
            out.append(f'{len(unstable)} unstable pole(s): '
                       + ', '.join(f'{z.real:.3g}{z.imag:+.3g}j' for z in unstable))
        return out

    def predict(self, u: FloatArray, y: FloatArray, span: Span) -> FloatArray:
        """Simulate each window from the measured positions before it.

        Returns
        -------
        FloatArray
            Predicted positions at the scored samples, shape (windows, horizon).

        """
        return _simulate(np.concatenate((self.a, self.b)), u, y, span)

    def fit(self, u: FloatArray, y: FloatArray, span: Span) -> float:
        """Fit [%] of the windowed prediction (MATLAB's definition)."""
        return fit_percent(y[span.scored()], self.predict(u, y, span))


@njit(cache=True)
def _simulate_windows(theta: np.ndarray, u: np.ndarray, y: np.ndarray, first: np.ndarray,
                      horizon: int, out: np.ndarray) -> None:
    a1, a2, b1, b2, b3 = theta[0], theta[1], theta[2], theta[3], theta[4]
    for w in range(first.shape[0]):
        k0 = first[w]
        x1, x2, x3 = y[k0 - 1], y[k0 - 2], y[k0 - 3]
        for j in range(horizon):
            k = k0 + j
            step = -a1 * (x1 - x2) - a2 * (x2 - x3) + b1 * u[k - 1] + b2 * u[k - 2] \
                + b3 * u[k - 3]
            x1, x2, x3 = x1 + step, x1, x2
            out[w, j] = x1


def _simulate(theta: FloatArray, u: FloatArray, y: FloatArray, span: Span) -> FloatArray:
    """Windowed simulation of the increments' model, each window from measured outputs."""
    out = np.empty((span.count, span.horizon))
    _simulate_windows(np.asarray(theta, dtype=float), np.ascontiguousarray(u, dtype=float),
                      np.ascontiguousarray(y, dtype=float), span.scored()[:, 0], span.horizon,
                      out)
    return out


def arx_third_order(u: FloatArray, y: FloatArray, rows: IntArray) -> FloatArray:
    """Equation-error least squares of ``[a1, a2, b1, b2, b3]`` on the target samples rows.

    Raises
    ------
    FitError
        If the regression is singular (a constant input) or there are too few rows.

    """
    k = np.asarray(rows, dtype=np.int64)
    k = k[k >= ORDER]
    if len(k) < 5 * ORDER:
        msg = f'{len(k)} samples are too few for the third-order regression'
        raise FitError(msg)
    dy = np.diff(y, prepend=y[0])
    design = np.column_stack((-dy[k - 1], -dy[k - 2], u[k - 1], u[k - 2], u[k - 3]))
    scale = np.max(np.abs(design), axis=0)
    if np.any(scale == 0.0):
        raise FitError('the input or the output is constant: nothing to identify')
    theta, _, rank, _ = np.linalg.lstsq(design / scale, dy[k], rcond=None)
    if rank < design.shape[1]:
        raise FitError('the third-order regression is singular (too little excitation)')
    return np.asarray(theta / scale, dtype=float)


def identify_third_order(u: FloatArray, y: FloatArray, period: float,
                         estimation: Span) -> ThirdOrderModel:
    """Identify the model on the estimation windows.

    The equation-error (ARX) least squares gives the start. The refinement is an output-error
    fit, as MATLAB's ``oe``/``tfest``: nonlinear least squares of the windowed simulation
    error over the continuous coefficients of
    ``G(s) = (c2 s^2 + c1 s + c0) / (s (s^2 + d1 s + d0))`` (d1, d0 searched in log scale, so
    the poles stay stable), each candidate sampled by the zero-order hold. It removes the bias
    that noise and the closed loop give the equation error, makes the model the best linear
    one by the criterion the project model is judged by, and keeps it continuous: an ARX fit
    to closed-loop data can land a sampled pole near z = -1, which no continuous model has.

    Parameters
    ----------
    u : FloatArray
        Input at every sample (held over the following period).
    y : FloatArray
        Measured position at every sample [m].
    period : float
        Sample period [s].
    estimation : Span
        The estimation windows (burn-in ignored: the model starts from measured outputs).

    Raises
    ------
    FitError
        If the regression is singular or there are too few samples.

    """
    span = Span(estimation.starts + estimation.burn_in, estimation.horizon)
    arx = arx_third_order(u, y, span.scored().ravel())
    measured = y[span.scored()]
    num, den, method = _to_continuous(arx[:2], arx[2:], period)
    c = np.concatenate((np.zeros(3 - min(len(num), 3)), num[-3:]))
    d1, d0 = (den[1], den[2]) if len(den) == 4 else (0.0, 0.0)
    if method != 'zoh' or not (d1 > 0.0 and d0 > 0.0 and math.isfinite(d1 + d0)):
        # A generic start: the regression's velocity gain through a 5 Hz, 0.7 damped pair.
        gain = float(np.sum(arx[2:]) / (1.0 + arx[0] + arx[1]) / period)
        d0 = (2.0 * math.pi * 5.0) ** 2
        d1 = 2.0 * 0.7 * math.sqrt(d0)
        c = np.array([0.0, 0.0, gain * d0])
    scale = max(float(np.max(np.abs(c))), 1e-30)
    start = np.array([c[0] / scale, c[1] / scale, c[2] / scale, math.log(d1), math.log(d0)])

    def discrete(x: FloatArray) -> FloatArray:
        return sample_zoh(x[:3] * scale, math.exp(x[3]), math.exp(x[4]), period)

    def error(x: FloatArray) -> FloatArray:
        if not np.all(np.abs(x[3:]) < 50.0):
            return np.full(measured.size, 1.0)
        out = _simulate(discrete(x), u, y, span) - measured
        return np.asarray(np.where(np.isfinite(out), out, 1.0).ravel(), dtype=float)

    refined = least_squares(error, start, method='lm', xtol=1e-8, ftol=1e-8, max_nfev=100)
    x = np.asarray(refined.x, dtype=float)
    if not np.sum(refined.fun ** 2) <= np.sum(error(start) ** 2):
        x = start
    theta = discrete(x)
    num, den = _monic(x[:3] * scale, np.array([1.0, math.exp(x[3]), math.exp(x[4]), 0.0]))
    return ThirdOrderModel(theta[:2], theta[2:], period, num, den, 'zoh')


def sample_zoh(num: FloatArray, d1: float, d0: float, period: float) -> FloatArray:
    """Sample ``num(s) / (s (s^2 + d1 s + d0))`` by the zero-order hold.

    Returns ``[a1, a2, b1, b2, b3]`` (num of degree 2, highest power first) of the sampled
    ``G(z) = (b1 z^2 + b2 z + b3) / ((z - 1)(z^2 + a1 z + a2))``: the exponential of the
    controllable canonical form augmented by the input, then its transfer function.
    """
    a = np.array([[-d1, -d0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    augmented = np.zeros((4, 4))
    augmented[:3, :3] = a * period
    augmented[0, 3] = period
    sampled = expm(augmented)
    phi, gamma = sampled[:3, :3], sampled[:3, 3:]
    num_z, den_z = ss2tf(phi, gamma, np.asarray(num, dtype=float).reshape(1, 3),
                         np.zeros((1, 1)))
    quotient, _ = np.polydiv(np.asarray(den_z, dtype=float), [1.0, -1.0])
    return np.concatenate((quotient[1:3], np.asarray(num_z, dtype=float).ravel()[-3:]))


def discrete_polynomials(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Numerator and denominator of G(z) in powers of z, highest first."""
    den = np.polymul([1.0, -1.0], [1.0, a[0], a[1]])
    return np.asarray(b, dtype=float), np.asarray(den, dtype=float)


def _to_continuous(a: FloatArray, b: FloatArray,
                   period: float) -> tuple[FloatArray, FloatArray, str]:
    num_z, den_z = discrete_polynomials(a, b)
    # Controllable canonical form of G(z) = (b1 z^2 + b2 z + b3) / (z^3 + d1 z^2 + d2 z + d3).
    phi = np.zeros((3, 3))
    phi[0, :] = -den_z[1:]
    phi[1, 0] = phi[2, 1] = 1.0
    gamma = np.array([[1.0], [0.0], [0.0]])
    c = num_z.reshape(1, 3)
    augmented = np.zeros((4, 4))
    augmented[:3, :3] = phi
    augmented[:3, 3:] = gamma
    augmented[3, 3] = 1.0
    eigen = np.linalg.eigvals(phi)
    if not np.any((np.abs(eigen.imag) < 1e-12) & (eigen.real <= 0.0)):
        log = np.asarray(logm(augmented), dtype=complex) / period
        if np.max(np.abs(log.imag)) < 1e-8 * max(1.0, float(np.max(np.abs(log.real)))):
            a_c, b_c = log.real[:3, :3], log.real[:3, 3:]
            num, den = ss2tf(a_c, b_c, c, np.zeros((1, 1)))
            return (*_monic(np.asarray(num[0], dtype=float), np.asarray(den, dtype=float)),
                    'zoh')
    # A sampled pole on the negative real axis has no continuous ZOH image: use Tustin.
    return (*_tustin_inverse(num_z, den_z, period), 'tustin')


def _monic(num: FloatArray, den: FloatArray) -> tuple[FloatArray, FloatArray]:
    num = np.trim_zeros(np.where(np.abs(num) < 1e-12 * np.max(np.abs(num)), 0.0, num), 'f')
    return num / den[0], den / den[0]


def _tustin_inverse(num_z: FloatArray, den_z: FloatArray,
                    period: float) -> tuple[FloatArray, FloatArray]:
    """Substitute z = (1 + s T/2) / (1 - s T/2) into G(z)."""
    order = len(den_z) - 1
    half = period / 2.0

    def substitute(poly: FloatArray) -> FloatArray:
        poly = np.concatenate((np.zeros(order + 1 - len(poly)), poly))
        total = np.zeros(order + 1)
        for i, coefficient in enumerate(poly):
            power = order - i
            term = np.polymul(_power([half, 1.0], power), _power([-half, 1.0], order - power))
            total = np.polyadd(total, coefficient * term)
        return np.asarray(total, dtype=float)

    return _monic(substitute(num_z), substitute(den_z))


def _power(poly: list[float], exponent: int) -> FloatArray:
    out = np.array([1.0])
    for _ in range(exponent):
        out = np.polymul(out, poly)
    return np.asarray(out, dtype=float)
