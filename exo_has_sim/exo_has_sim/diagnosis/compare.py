"""Windows of a record, the estimation/validation split, and MATLAB's fit percentage.

The record is cut into windows whose scored samples follow each other (see
:mod:`exo_has_sim.diagnosis.plants` for why a model is compared window by window). Each window
starts from the measured state, runs an unscored burn-in (0.1 s by default: the hydraulic mode
that an imperfect initial velocity excites decays by e^-2 within it), then is scored over its
horizon (:data:`DEFAULT_HORIZON`, 0.5 s: long enough for a dead zone or an extra leakage to
move the position far beyond the sensor noise, short enough that the drift of an integrating
plant stays a small part of the error). Every :data:`VALIDATION_EVERY`-th window is held out
for validation and the others estimate: the split interleaves blocks, so that both segments
see every phase of the excitation (a walking trial followed by a squat, a pressure peak that
happens once), which a split of the record into a first and a last part would not. The windows
are simulated independently, each from its own measured initial state, so no estimation
window carries information into a validation one beyond the physics both share (a validation
window's burn-in reads the end of the window before it as input only).

``fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` [%] per output, as MATLAB's ``compare``
(normalised root-mean-square error), over the concatenated validation windows.

What the nominal model reaches where it is the plant: on the bags of eight sessions of ours (four
of ``exo-has demo``, four of test/test_session.py; each joint, 32 records), every window starting
from the state the plant was in, the validated fits were 99.0 to 99.96 % for the position, 97.6 to
99.8 % for the motor speed and 88.9 to 97.5 % for the pressure (at most 93.2 % at the hips), and no
validation window erred by more than 0.30 mm, 5.2 rad/s and 0.33 MPa RMS. Not 100 % because of the
sampling: the plant node ticks when its timer fires, 0.1 to 24 ms apart, and integrates each span
under the newest command and load, while the record is resampled onto a uniform grid (the states
interpolated, the command averaged over each period, to which the motor's 5 ms lag answers
otherwise than to its parts), which moves a motor's reversal by part of a period, where the compact
valve's free mode drains the chamber within milliseconds (the window that erred most, a knee's,
held one). The plant node does not quantise its states (float64 throughout); its own integration,
at looser tolerances than the diagnosis', accounts for up to 20 um in a window. Replayed on the
ticks' own times, the bag's states come back to 0.03 um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from exo_has_sim.errors import DiagnosisError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: One window in this many is held out for validation.
VALIDATION_EVERY = 3
#: Default prediction horizon [s].
DEFAULT_HORIZON = 0.5


@dataclass(frozen=True)
class Span:
    """Windows to simulate, each from the measured state at its start.

    A window runs ``burn_in`` samples unscored, then ``horizon`` scored samples.

    Attributes
    ----------
    starts : IntArray
        Sample whose measured state starts each window's simulation.
    horizon : int
        Scored samples per window.
    burn_in : int
        Samples simulated before the scored ones.

    """

    starts: IntArray
    horizon: int
    burn_in: int = 0

    @property
    def steps(self) -> int:
        """Samples simulated per window."""
        return self.burn_in + self.horizon

    @property
    def count(self) -> int:
        """Number of windows."""
        return len(self.starts)

    def scored(self) -> IntArray:
        """Return the indices of the scored samples, shape (windows, horizon)."""
        first = self.starts + self.burn_in + 1
        return np.asarray(first[:, None] + np.arange(self.horizon)[None, :], dtype=np.int64)


@dataclass(frozen=True)
class Windows:
    """Consecutive windows of a record, split into estimation and validation.

    Attributes
    ----------
    span : Span
        Every window.
    validation : NDArray[np.bool_]
        Whether each window is held out for validation.

    """

    span: Span
    validation: NDArray[np.bool_]

    @property
    def horizon(self) -> int:
        """Scored samples per window."""
        return self.span.horizon

    @property
    def estimation_span(self) -> Span:
        """The estimation windows."""
        return Span(self.span.starts[~self.validation], self.span.horizon, self.span.burn_in)

    @property
    def validation_span(self) -> Span:
        """The validation windows."""
        return Span(self.span.starts[self.validation], self.span.horizon, self.span.burn_in)


def make_windows(samples: int, horizon: int, first: int = 0, burn_in: int = 0,
                 validation_every: int = VALIDATION_EVERY) -> Windows:
    """Cut the record into windows whose scored samples follow each other.

    Window i starts its simulation at sample ``first + i horizon`` and scores the ``horizon``
    samples after its ``burn_in``; it is a validation window when
    ``i % validation_every == validation_every - 1``.

    Raises
    ------
    DiagnosisError
        If fewer than ``validation_every`` windows fit.

    """
    if horizon < 2 or burn_in < 0:
        msg = f'the horizon must span at least 2 samples and the burn-in none or more, got ' \
              f'{horizon} and {burn_in}'
        raise DiagnosisError(msg)
    count = (samples - 1 - first - burn_in) // horizon
    if count < validation_every:
        msg = (f'{samples} samples hold {max(count, 0)} windows of {horizon} samples after '
               f'sample {first}; at least {validation_every} are needed (a shorter horizon '
               'or a longer record)')
        raise DiagnosisError(msg)
    starts = first + horizon * np.arange(count, dtype=np.int64)
    validation = (np.arange(count) % validation_every) == validation_every - 1
    return Windows(Span(starts, horizon, burn_in), validation)


def fit_percent(measured: FloatArray, predicted: FloatArray) -> float:
    """MATLAB's fit [%]: ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` over all samples.

    Raises
    ------
    DiagnosisError
        If the arrays differ in shape or the measurement is constant.

    """
    y = np.asarray(measured, dtype=float).ravel()
    y_hat = np.asarray(predicted, dtype=float).ravel()
    if y.shape != y_hat.shape:
        msg = f'measured and predicted differ in shape: {y.shape}, {y_hat.shape}'
        raise DiagnosisError(msg)
    spread = float(np.linalg.norm(y - np.mean(y)))
    if spread == 0.0:
        raise DiagnosisError('a constant measurement has no fit percentage')
    return 100.0 * (1.0 - float(np.linalg.norm(y - y_hat)) / spread)


def effective_samples(residuals: FloatArray, max_lag: int | None = None) -> float:
    """Count the independent samples residuals are worth, from their autocorrelation.

    ``residuals`` has shape (windows, horizon); the autocorrelation is averaged over the
    windows and summed over lags up to its first negative value (Geyer's initial positive
    sequence, simplified): ``N_eff = N / (1 + 2 sum rho_k)``, at least one per window.
    """
    r = np.asarray(residuals, dtype=float)
    windows, horizon = r.shape
    lags = horizon - 1 if max_lag is None else min(max_lag, horizon - 1)
    centred = r - np.mean(r)
    variance = float(np.mean(centred ** 2))
    if variance == 0.0:
        return float(windows)
    tau = 1.0
    for k in range(1, lags + 1):
        rho = float(np.mean(centred[:, k:] * centred[:, :-k])) / variance
        if rho <= 0.0:
            break
        tau += 2.0 * rho
    return max(float(windows), r.size / tau)


def horizon_samples(horizon: float, period: float) -> int:
    """Return the samples in a horizon of ``horizon`` seconds."""
    if not (math.isfinite(horizon) and horizon > 0.0):
        msg = f'the horizon must be positive [s], got {horizon!r}'
        raise DiagnosisError(msg)
    return max(2, round(horizon / period))
