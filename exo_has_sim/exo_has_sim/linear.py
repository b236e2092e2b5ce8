"""Linear models of the HAS: the paper's Eq. 12 to 15, and a linearisation of the nonlinear model.

Transfer functions are ``(num, den)`` pairs of polynomial coefficients in s, highest power first.
Eq. 12 gives x/n_p [m per rad/s]; the paper's identified Eq. 15 is given as printed, in the
paper's (unstated) units.

Eqs. 12-14 take the area of the flow balance as ``flow_area``: by default the model's,
:attr:`~exo_has_sim.parameters.HasParameters.flow_area` (A_A, Eq. 4), which makes them the
linearisation of :mod:`exo_has_sim.model`; the paper prints them with the average of Eq. 10,
:func:`averaged_flow_area`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from exo_has_sim.parameters import HasParameters

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Zeros and poles of the paper's identified nominal open-loop G(s), Eq. 15 [rad/s].
EQ15_ZEROS = (-149.38, -9.58)
EQ15_POLES = (-0.24, -5.53, -26.21)


@dataclass(frozen=True)
class TransferFunction:
    """A SISO transfer function num(s)/den(s)."""

    num: FloatArray
    den: FloatArray

    def __call__(self, s: ArrayLike) -> ComplexArray:
        """Evaluate at complex frequencies s."""
        values = np.asarray(s, dtype=complex)
        return np.asarray(np.polyval(self.num, values) / np.polyval(self.den, values),
                          dtype=complex)

    def frequency_response(self, frequency_hz: ArrayLike) -> ComplexArray:
        """Complex response at frequencies [Hz]."""
        return self(2j * math.pi * np.asarray(frequency_hz, dtype=float))

    def poles(self) -> ComplexArray:
        """Roots of the denominator [rad/s]."""
        return np.asarray(np.roots(self.den), dtype=complex)


def _volume(params: HasParameters, position: float) -> float:
    return params.dead_volume + params.area_a * position


def averaged_flow_area(params: HasParameters) -> float:
    """Return the paper's flow area (A_A + A_B) / 2 [m^2] (Eq. 10), as it prints Eqs. 12-14."""
    return 0.5 * (params.area_a + params.area_b)


def _flow_area(params: HasParameters, flow_area: float | None) -> float:
    return params.flow_area if flow_area is None else flow_area


def eq12(params: HasParameters, position: float | None = None,
         flow_area: float | None = None) -> TransferFunction:
    """Eq. 12, x/n_p, with V_A the rodless volume at ``position`` (default mid stroke).

    ``x/n_p = (A_A E D_p / (V M)) / (s^3 + (E L_n / V + B / M) s^2
    + (L_n E B / (V M) + A_A E A_f / (V M)) s)`` with ``A_f`` the ``flow_area`` [m^2] (default
    the model's; the paper prints :func:`averaged_flow_area`).
    """
    x = params.stroke / 2.0 if position is None else position
    volume = _volume(params, x)
    e, m, b, ln = params.bulk_modulus, params.moving_mass, params.damping, params.pump_leakage
    a_a, a_f = params.area_a, _flow_area(params, flow_area)
    gain = a_a * e * params.pump_displacement / (volume * m)
    den = np.array([1.0, e * ln / volume + b / m,
                    ln * e * b / (volume * m) + a_a * e * a_f / (volume * m), 0.0])
    return TransferFunction(np.array([gain]), den)


def natural_frequency(params: HasParameters, position: float | None = None,
                      flow_area: float | None = None) -> float:
    """Eq. 13, omega_n [rad/s] of the velocity response (``flow_area`` as for :func:`eq12`)."""
    x = params.stroke / 2.0 if position is None else position
    volume = _volume(params, x)
    term = params.pump_leakage * params.damping \
        + _flow_area(params, flow_area) * params.area_a
    return math.sqrt(term * params.bulk_modulus / (volume * params.moving_mass))


def velocity_gain(params: HasParameters, flow_area: float | None = None) -> float:
    """Eq. 14, K [m/s per rad/s]: steady extension velocity per pump speed, without load.

    ``K = D_p A_A / (L_n B + A_f A_A)``, ``flow_area`` as for :func:`eq12`.
    """
    a_a = params.area_a
    return params.pump_displacement * a_a / (
        params.pump_leakage * params.damping + _flow_area(params, flow_area) * a_a)


def eq15() -> TransferFunction:
    """Return the paper's identified nominal open-loop G(s), Eq. 15, as printed."""
    return TransferFunction(np.poly(EQ15_ZEROS).real, np.poly(EQ15_POLES).real)


@dataclass(frozen=True)
class StateSpace:
    """dx/dt = A x + B u, y = C x, from the pump speed u to the cylinder position y."""

    a: FloatArray
    b: FloatArray
    c: FloatArray

    def frequency_response(self, frequency_hz: ArrayLike) -> ComplexArray:
        """Complex response y/u at frequencies [Hz]."""
        out = []
        identity = np.eye(self.a.shape[0])
        for f in np.atleast_1d(np.asarray(frequency_hz, dtype=float)):
            out.append((self.c @ np.linalg.solve(2j * math.pi * f * identity - self.a, self.b))
                       .item())
        return np.array(out)


def linearize(params: HasParameters, position: float | None = None,
              load_force: float = 0.0) -> StateSpace:
    """Linearise the nonlinear model in assist at rest, from pump speed to position.

    Central differences of :func:`exo_has_sim.model.rhs` in the states (x, v, p_A), with the
    spool in assist and the motor speed as the input (the motor loop is left out, as in Eq. 12).
    """
    # Imported here: the model is compiled with numba, which the controller, that reads only
    # the closed-form gains above, does not need.
    from exo_has_sim import model

    x0 = params.stroke / 2.0 if position is None else position
    y0 = model.initial_state(params, x0, load_force)
    prm = model.pack(params)
    states = (model.X, model.V, model.PA)
    scale = (1e-6, 1e-6, 1e2)

    def derivative(y: FloatArray) -> FloatArray:
        out = np.zeros(model.N_STATE)
        model.rhs(y, y[model.N], load_force, prm, out)
        return out[list(states)]

    a = np.empty((3, 3))
    for j, (index, step) in enumerate(zip(states, scale, strict=True)):
        plus, minus = y0.copy(), y0.copy()
        plus[index] += step
        minus[index] -= step
        a[:, j] = (derivative(plus) - derivative(minus)) / (2.0 * step)
    # The pump speed enters the pressure equation as D_p n_p / C; differentiate through n.
    plus, minus = y0.copy(), y0.copy()
    plus[model.N] += 1e-3
    minus[model.N] -= 1e-3
    b = ((derivative(plus) - derivative(minus)) / 2e-3).reshape(3, 1)
    return StateSpace(a, b, np.array([[1.0, 0.0, 0.0]]))


def pd_closed_loop(plant: TransferFunction, kp: float, kd: float) -> TransferFunction:
    """Return the closed loop T = C G / (1 + C G) of a PD controller C = kp + kd s on G."""
    controller = np.array([kd, kp])
    num = np.polymul(controller, plant.num)
    den = np.polyadd(plant.den, num)
    return TransferFunction(np.asarray(num, dtype=float), np.asarray(den, dtype=float))


def bandwidth(system: TransferFunction, max_hz: float = 500.0) -> float:
    """Lowest frequency [Hz] at which |T| falls 3 dB below its low-frequency value."""
    frequency = np.logspace(-3, math.log10(max_hz), 20000)
    magnitude = np.abs(system.frequency_response(frequency))
    reference = magnitude[0]
    below = np.nonzero(magnitude < reference / math.sqrt(2.0))[0]
    if below.size == 0:
        return math.inf
    i = below[0]
    if i == 0:
        return float(frequency[0])
    # Interpolate in log frequency between the last point above and the first below.
    target = reference / math.sqrt(2.0)
    f0, f1 = math.log10(frequency[i - 1]), math.log10(frequency[i])
    m0, m1 = magnitude[i - 1], magnitude[i]
    return float(10 ** (f0 + (target - m0) * (f1 - f0) / (m1 - m0)))
