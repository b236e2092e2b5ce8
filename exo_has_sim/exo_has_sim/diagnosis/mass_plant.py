"""A generic position actuator as a plant the diagnosis fits: a mass driven by a force.

``M dv/dt = F(t - delay) - F_v v - F_c sign(v) - offset`` with an optional force dead zone,
integrated over windows by implicit Euler with exact stick-slip (the velocity is zero while
the net force stays within the Coulomb level), which keeps a sharp sign(v) stable at any step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from exo_has_sim.diagnosis.data import Measurement
from exo_has_sim.diagnosis.effects import effects_of, mass_effect_parameters
from exo_has_sim.diagnosis.plants import (
    Candidate,
    FloatArray,
    IntArray,
    Parameter,
    WindowedModel,
    smooth,
)
from exo_has_sim.errors import DiagnosisError


@njit(cache=True)
def _held_integral(cumulative: np.ndarray, force: np.ndarray, period: float, t: float) -> float:
    """Integral from 0 to t [s] of the input held over each sample period."""
    i = min(max(math.floor(t / period), 0), force.shape[0] - 1)
    return float(cumulative[i] + (t - i * period) * force[i])


@njit(cache=True)
def _mass_windows(prm: np.ndarray, cumulative: np.ndarray, force: np.ndarray,
                  starts: np.ndarray, x0: np.ndarray, v0: np.ndarray, horizon: int,
                  period: float, substeps: int, out: np.ndarray) -> None:
    """Integrate the mass plant over windows for candidates ``prm`` (M, Fv, F0, Fc, d, Fdz).

    The initial positions and velocities ``x0``, ``v0`` have shape (candidates, windows).

    The force acting over each substep is the mean of the delayed, held input over it
    (``cumulative`` is its running integral), so the result is continuous in the delay.
    Implicit Euler in the velocity with exact stick-slip, explicit in the position.
    """
    h = period / substeps
    for c in range(prm.shape[0]):
        mass, fv, offset, fc, delay, dead = (prm[c, 0], prm[c, 1], prm[c, 2], prm[c, 3],
                                             prm[c, 4], prm[c, 5])
        for w in range(starts.shape[0]):
            x = x0[c, w]
            v = v0[c, w]
            t = starts[w] * period - delay
            below = _held_integral(cumulative, force, period, t)
            for k in range(horizon):
                for _ in range(substeps):
                    above = _held_integral(cumulative, force, period, t + h)
                    f = (above - below) / h
                    below = above
                    t += h
                    if dead > 0.0:
                        f = math.copysign(max(abs(f) - dead, 0.0), f)
                    drive = mass * v / h + f - offset
                    if abs(drive) <= fc:
                        v = 0.0
                    else:
                        v = (drive - math.copysign(fc, drive)) / (mass / h + fv)
                    x += h * v
                out[c, w, k] = x


class MassPlant(WindowedModel):
    """A generic position actuator: a mass with viscous damping and a force offset.

    ``M dv/dt = F - F_v v - offset``, input ``force`` [N], output ``position`` [m]. The
    baseline fits M, F_v and the offset (a constant force: gravity on an inclined axis, a
    sensor offset); the effects that apply are Coulomb friction, a transport delay of the
    force, and a force dead zone (the library's pump_deadzone read as force).

    Parameters
    ----------
    measurement : Measurement
        The data (plant ``'mass'``).
    mass : float
        Nominal moving mass [kg] (``--load-mass``), the start of its fit.

    """

    kind = 'mass'
    outputs = ('position',)
    #: Longest integration step [s]: implicit Euler's relative error is about step / (2 M/F_v),
    #: 0.04 % for the 0.3 s time constant of a 40 kg mass on 120 N s/m.
    MAX_STEP = 2.5e-4

    def __init__(self, measurement: Measurement, mass: float = 50.0) -> None:
        if not (math.isfinite(mass) and mass > 0.0):
            msg = f'the moving mass must be positive and finite [kg], got {mass!r}'
            raise DiagnosisError(msg)
        self.measurement = measurement
        self.mass = mass
        period = measurement.period
        self._x = smooth(measurement.position, period)
        self._v = smooth(measurement.position, period, 1)
        self._a = smooth(measurement.position, period, 2)
        force = measurement.input
        self._force = np.ascontiguousarray(force, dtype=float)
        self._cumulative = np.concatenate(([0.0], np.cumsum(force)[:-1])) * period
        # Starting values by least squares on the smoothed motion (an inverse-model guess).
        design = np.column_stack((self._a, self._v, np.ones_like(self._v)))
        coef = np.linalg.lstsq(design, force, rcond=None)[0]
        self._start_mass = float(np.clip(coef[0], 0.1 * mass, 10.0 * mass))
        scale = float(np.std(force)) / max(float(np.std(self._v)), 1e-9)
        self._start_damping = float(np.clip(coef[1], 1e-2 * scale, 10.0 * scale))
        self._force_scale = max(float(np.std(force)), 1e-6)
        self._start_offset = float(coef[2])

    @property
    def baseline(self) -> tuple[Parameter, ...]:
        """Mass M, viscous friction F_v and the force offset."""
        m, fv, f0 = self._start_mass, self._start_damping, self._start_offset
        bound = float(np.max(np.abs(self._force)))
        return (Parameter('mass', 'kg', m, m / 20.0, m * 20.0, 'moving mass M'),
                Parameter('viscous_friction', 'N s/m', fv, fv / 100.0, fv * 100.0,
                          'viscous friction F_v'),
                Parameter('offset', 'N', f0, min(-bound, f0), max(bound, f0),
                          'constant force opposing the input (gravity, a sensor offset)',
                          scale=0.05 * self._force_scale))

    @property
    def effects(self) -> tuple[str, ...]:
        """Coulomb friction, a force dead zone and transport delay (:func:`effects_of`)."""
        return effects_of(self.kind)

    def effect_parameters(self, effect: str) -> tuple[Parameter, ...]:
        """Size parameters of the mass plant's effects."""
        return mass_effect_parameters(effect, float(np.max(np.abs(self._force))))

    def simulate(self, candidates: Sequence[Candidate], starts: IntArray, horizon: int,
                 burn_in: int = 0) -> FloatArray:
        """Predict the position over the windows for each candidate.

        A mass forgets an error of its initial velocity only over M/F_v (0.15 to 0.5 s), and a
        velocity differentiated from a noisy position is noisy: its errors would bias the
        fit (errors in variables). So the burn-in samples, which are not scored, estimate each
        window's initial position and velocity: the model is linear in them but for the
        friction's sign, and one run with the velocity perturbed gives the sensitivity, so
        a 2 x 2 least-squares step per window corrects them, and a third run predicts.
        """
        starts = np.asarray(starts, dtype=np.int64)
        if starts.min() < self.first_start or starts.max() + horizon >= self.measurement.samples:
            raise DiagnosisError('a window reaches outside the record')
        prm = np.array([[float(c.get('mass', self._start_mass)),
                         float(c.get('viscous_friction', self._start_damping)),
                         float(c.get('offset', self._start_offset)),
                         float(c.get('coulomb_friction', 0.0)),
                         float(c.get('transport_delay', 0.0)),
                         float(c.get('pump_deadzone', 0.0))] for c in candidates])
        period = self.measurement.period
        substeps = max(1, math.ceil(period / self.MAX_STEP - 1e-9))
        shape = (len(candidates), len(starts))
        x0 = np.broadcast_to(self._x[starts], shape).copy()
        v0 = np.broadcast_to(self._v[starts], shape).copy()

        def run(x: FloatArray, v: FloatArray, steps: int) -> FloatArray:
            out = np.empty((*shape, steps))
            _mass_windows(prm, self._cumulative, self._force, starts, x, v, steps, period,
                          substeps, out)
            return out

        if burn_in >= 3:
            step = max(float(np.std(self._v)), 1e-9) * 1e-3
            base = run(x0, v0, burn_in)
            sensitivity = (run(x0, v0 + step, burn_in) - base) / step
            error = self.measurement.position[starts[:, None] + np.arange(1, burn_in + 1)] \
                - base
            # Least squares of error = dx + sensitivity dv, per candidate and window.
            n = float(burn_in)
            s1, s2 = sensitivity.sum(axis=-1), (sensitivity ** 2).sum(axis=-1)
            e1, es = error.sum(axis=-1), (error * sensitivity).sum(axis=-1)
            det = n * s2 - s1 * s1
            good = det > 1e-12 * n * s2
            dv = np.where(good, (n * es - s1 * e1) / np.where(good, det, 1.0), 0.0)
            x0 += np.where(good, (e1 - s1 * dv) / n, 0.0)
            v0 += dv
        return run(x0, v0, horizon)[..., None]
