"""What the diagnosis fits: a plant's parameters, and the plant over windows of a measurement.

A plant here is the model of one actuator as a function of its parameters, a
:class:`WindowedModel`: given parameter candidates (dicts of values by name) and the windows of a
measurement, it returns the outputs it predicts in every window, for all candidates at once, so
that a finite-difference Jacobian or a grid over an effect's size costs one call. The plants are
:class:`~exo_has_sim.diagnosis.has_plant.HasPlant` (the project's HAS model) and
:class:`~exo_has_sim.diagnosis.mass_plant.MassPlant` (a generic mass); the simulated HAS that
the nodes run is another thing, :class:`exo_has_sim.plant.Plant`.

Comparison over windows. A hydraulic cylinder integrates the pump's flow, so a simulation run
open loop from the measured command over a whole record drifts with any small error of the
flow gain or leakage, and the drift, not the dynamics, then dominates the error. The record is
cut into windows; each window starts from the measured state at its first sample and is
simulated from the measured input (and load) alone, through an unscored burn-in, then over the
scored horizon (a multi-step-ahead prediction, as MATLAB's ``compare`` with a prediction
horizon, or a multiple-shooting simulation; see :mod:`~exo_has_sim.diagnosis.compare`). The
initial state of a window comes from the data: the position and, when measured, the pressure,
smoothed by a local cubic (Savitzky-Golay) fit over :data:`SMOOTHING_TIME`, which also gives
the velocity (and a HAS's measured motor speed, see
:class:`~exo_has_sim.diagnosis.has_plant.HasPlant`). A window's inputs include those sent
before it, so a transport delay acts on the true earlier commands.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from exo_has_sim.diagnosis.compare import Span
from exo_has_sim.diagnosis.data import Measurement
from exo_has_sim.errors import DiagnosisError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Candidate = Mapping[str, float]

#: Span of the local cubic fit that smooths the measured signals for the initial states [s].
SMOOTHING_TIME = 0.05
#: Largest transport delay a plant can be given [s]; windows start after it.
MAX_DELAY = 0.1
GRAVITY = 9.81  # m/s^2


@dataclass(frozen=True)
class Parameter:
    """A parameter a diagnosis can fit, in SI units, searched between bounds.

    A positive parameter is searched in log scale (a relative step means the same for a
    leakage of 1e-13 and a modulus of 1e9); one that may take either sign (a force offset),
    linearly in units of ``scale``.

    Attributes
    ----------
    name : str
        Identifier (an attribute of :class:`exo_has_sim.parameters.HasParameters` or
        :class:`~exo_has_sim.parameters.Effects` for the HAS).
    unit : str
        SI unit.
    start : float
        Starting value of a fit.
    lower, upper : float
        Bounds.
    description : str
        What it is.
    scale : float or None
        None for a log-scale search (bounds then positive); else the size of a unit step
        of the linear search.
    grid : tuple[float, ...]
        Plausible values tried before a fit (an effect's size); empty for none.
    prior : float or None
        Standard deviation, in the search coordinate, of a Gaussian prior centred on
        ``start`` (for a log-scale parameter, 0.2 is about +-20 %): what the parameters
        file's value is worth. None: no prior, the data alone decide.
    negligible_floor : bool
        Whether the lower bound stands for "none of it" (a damping or a leakage too small to
        matter), so that a fit ending there says only that the data need none, not that the
        model's structure is wrong (:mod:`~exo_has_sim.diagnosis.structure`).

    """

    name: str
    unit: str
    start: float
    lower: float
    upper: float
    description: str
    scale: float | None = None
    grid: tuple[float, ...] = ()
    prior: float | None = None
    negligible_floor: bool = False

    def __post_init__(self) -> None:
        positive = self.scale is not None or self.lower > 0.0
        if not (positive and self.lower <= self.start <= self.upper) \
                or (self.scale is not None and not self.scale > 0.0) \
                or (self.prior is not None and not self.prior > 0.0):
            msg = (f'parameter {self.name}: start {self.start!r} must lie within its bounds '
                   f'[{self.lower!r}, {self.upper!r}] (positive for a log-scale search), and a '
                   f'linear scale {self.scale!r} and a prior {self.prior!r} must be positive')
            raise DiagnosisError(msg)

    @property
    def log(self) -> bool:
        """Whether the parameter is searched in log scale."""
        return self.scale is None

    def to_search(self, value: float) -> float:
        """Search coordinate of a value."""
        if self.scale is None:
            return math.log(value / self.start)
        return (value - self.start) / self.scale

    def from_search(self, z: float) -> float:
        """Value of a search coordinate."""
        if self.scale is None:
            return self.start * math.exp(z)
        return self.start + z * self.scale

    def search_bounds(self) -> tuple[float, float]:
        """Bounds in the search coordinate."""
        return self.to_search(self.lower), self.to_search(self.upper)

    def moved(self, value: float, step: float) -> float:
        """Return ``value`` moved by ``step`` in the search coordinate, held within the bounds.

        The step is clipped in the search coordinate, before it is mapped back: a Gauss-Newton
        step from a nearly singular Jacobian can be huge, and ``exp`` of it would overflow.
        """
        low, high = self.search_bounds()
        return self.from_search(min(max(self.to_search(value) + step, low), high))


def smooth(values: FloatArray, period: float, derivative: int = 0) -> FloatArray:
    """Savitzky-Golay smoothing (cubic over :data:`SMOOTHING_TIME`) or its derivative."""
    length = max(5, 2 * round(SMOOTHING_TIME / period / 2.0) + 1)
    length = min(length, (len(values) - 1) // 2 * 2 + 1)
    result = savgol_filter(values, length, 3, deriv=derivative, delta=period, mode='interp')
    return np.asarray(result, dtype=float)


class WindowedModel(ABC):
    """A model of one actuator whose outputs can be predicted over windows of a measurement.

    What the diagnosis fits, as a function of its parameters (module docstring).

    Attributes
    ----------
    kind : str
        ``'has'`` or ``'mass'``.
    measurement : Measurement
        The data.
    outputs : tuple[str, ...]
        Measured outputs the model predicts (``position`` first).
    fixed : dict[str, float]
        Values of the baseline's parameters that are not fitted.

    """

    kind: str
    measurement: Measurement
    outputs: tuple[str, ...]

    @property
    @abstractmethod
    def baseline(self) -> tuple[Parameter, ...]:
        """Parameters of the baseline that are re-estimated (the hard-to-know ones)."""

    @property
    def limit_kind(self) -> str:
        """The kind of plant whose calibrated margins its detection limits take.

        :data:`exo_has_sim.diagnosis.limits.LIMIT_MARGIN`; the generic plant's own kind.
        """
        return self.kind

    @property
    def alternatives(self) -> dict[str, tuple[Parameter, ...]]:
        """Other structures of the baseline, which the data may call for, and what each adds.

        Not causes but the shape of the nominal model (the order of a speed loop): a
        diagnosis takes one when it predicts the held-out data significantly better, before
        it looks for effects.
        """
        return {}

    @property
    @abstractmethod
    def effects(self) -> tuple[str, ...]:
        """Ids of the effects this plant can be extended with."""

    @property
    def unidentifiable(self) -> dict[str, str]:
        """Effects the measured signals cannot identify, each with the reason (none here).

        A diagnosis neither names these nor states detection limits for them (whatever such
        an effect would explain, something unmeasured explains as well); it only checks them
        as rivals of what it names.
        """
        return {}

    @abstractmethod
    def effect_parameters(self, effect: str) -> tuple[Parameter, ...]:
        """Parameters of an effect in this plant; its first is the effect's size."""

    @abstractmethod
    def simulate(self, candidates: Sequence[Candidate], starts: IntArray, horizon: int,
                 burn_in: int = 0) -> FloatArray:
        """Predict the outputs over windows for each candidate.

        Parameters
        ----------
        candidates : Sequence[Mapping[str, float]]
            Parameter values by name; a name left out takes its nominal value, and an
            effect whose size is left out is off.
        starts : IntArray
            First sample of each window (its measured state is the initial state).
        horizon : int
            Samples predicted after each start.
        burn_in : int
            Leading samples of the horizon that are not scored (a plant may use them to
            refine its initial states).

        Returns
        -------
        FloatArray
            Shape (candidates, windows, horizon, outputs): the outputs at samples
            ``start + 1`` to ``start + horizon``.

        """

    @property
    def first_start(self) -> int:
        """Earliest window start: the inputs of the longest delay must exist before it."""
        return math.ceil(MAX_DELAY / self.measurement.period) + 2

    def measured(self, span: Span) -> FloatArray:
        """Measured outputs at the scored samples, shape (windows, horizon, outputs)."""
        index = span.scored()
        return np.stack([self.measurement.signal(name)[index] for name in self.outputs],
                        axis=-1)

    @property
    def linearises(self) -> bool:
        """Whether :meth:`predict` linearises at ``linearised_at`` (else it ignores it)."""
        return False

    def predict(self, candidates: Sequence[Candidate], span: Span,
                linearised_at: Candidate | None = None) -> FloatArray:
        """Predict the outputs at the scored samples.

        Returns an array of shape (candidates, windows, horizon, outputs). ``linearised_at``
        concerns a plant that projects part of its prediction out of the data
        (:meth:`HasPlant.predict <exo_has_sim.diagnosis.has_plant.HasPlant.predict>`); this
        one simulates exactly and ignores it.
        """
        return self.simulate(candidates, span.starts, span.steps,
                             span.burn_in)[:, :, span.burn_in:]

    def nominal(self) -> dict[str, float]:
        """Return the starting values of the baseline's fitted parameters."""
        return {p.name: p.start for p in self.baseline}
