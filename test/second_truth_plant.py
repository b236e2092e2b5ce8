"""A second, independently written truth plant of one HAS joint, run in closed loop at 200 Hz.

It makes measured data (CSV) on which ``exo-has diagnose`` can be tested, with a structure that
differs on purpose from the project's own model (``exo_has_sim.model``), so that a diagnosis that
only works on data of its own model fails here. It was written from the paper (Sun et al. 2021,
sections 2-3) and the parameter files alone.

Plant (state ``x, v, p_A, p_B, n, w``; all pressures gauge)::

    Q_p   = D_p eta_v n_e - L p_A [- L2 p_A |p_A|]          n_e = n, or the dead-zoned n
    C_A   = (V_dA + A_A x) / E_eff(p_A)                      E_eff = E, or oil with free air
    C_A dp_A/dt = Q_p - A_A v - Q_relief(p_A)                rodless chamber, its own state
    C_B dp_B/dt = A_B v - G_line (p_B - p_T)                 rod side: line to an elastic tank
    M dv/dt = A_A p_A - A_B p_B - B v - F_load(t) [- F_c tanh(v / 1e-3)] + F_stop(x, v)
    n' = w,  w' = w_m^2 (n_cmd(t [- tau]) - n) - 2 zeta w_m w,  |n| <= n_max

with ``C_B = (V_dB + A_B (stroke - x)) / E``, a pressure floor at -0.09 MPa on both chambers
(cavitation), stiff spring-damper end stops at 0 and the stroke, and ``Q_relief`` the 18 MPa
safety valve of the parameters file (plus the crack flow of the ``relief_valve`` effect).

Controller (200 Hz, zero-order hold, on the noisy quantised position): a PI law with velocity
feedforward, ``n_cmd = kff v_ref + kp e + ki sum(e) T``, ``kff = A_A / D_p`` (nominal),
``kp = 20e3 (rad/s)/m``, ``ki = 40e3 (rad/s)/(m s)``, saturated at the motor speed limit, with
conditional integration (no integration while saturated).

Integration: fixed-step RK4, ``SUBSTEPS`` steps per sample (numba, cached). A transport delay
splits the sample interval at the exact instant the delayed command changes.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit
from numpy.typing import NDArray
from rigs import motion_scale, rig_parameters

FloatArray = NDArray[np.float64]

EFFECTS = (
    'coulomb_friction',
    'pump_deadzone',
    'transport_delay',
    'quadratic_leakage',
    'relief_valve',
    'entrained_air',
)
EFFECT_CHOICES = ('none', *EFFECTS)
EXCITATIONS = ('sine_sum', 'gait')
JOINT_TYPES = ('hip', 'knee')
COLUMNS = (
    'time',
    'motor_speed_command',
    'position',
    'reference',
    'pressure_a',
    'pressure_b',
    'motor_speed',
    'load_force',
)

#: Size range of each effect (SI); drawn log-uniform, except the relief valve (linear).
EFFECT_RANGES: dict[str, tuple[float, float]] = {
    'coulomb_friction': (25.0, 150.0),
    'pump_deadzone': (5.0, 40.0),
    'transport_delay': (0.002, 0.020),
    'quadratic_leakage': (5e-21, 3e-20),
    'relief_valve': (8e6, 11e6),
    'entrained_air': (0.05, 0.2),
}
#: The end of each range where the effect is weakest (the relief valve: the highest crack).
WEAKEST_SIZE: dict[str, float] = {
    name: (hi if name == 'relief_valve' else lo) for name, (lo, hi) in EFFECT_RANGES.items()
}
#: Relative half-width of the uniform spread of each nuisance parameter around its nominal
#: value (the parameters file; flow_gain, the pump's volumetric efficiency, is nominally 1).
NUISANCE_SPREADS: dict[str, float] = {
    'bulk_modulus': 0.30,
    'pump_leakage': 0.30,
    'damping': 0.30,
    'dead_volume': 0.20,
    'motor_time_constant': 0.30,
    'flow_gain': 0.20,
}

RATE = 200.0
PERIOD = 1.0 / RATE
SUBSTEPS = 50
GRAVITY = 9.81
ATMOSPHERE = 101325.0
POLYTROPIC_EXPONENT = 1.4
FRICTION_VELOCITY = 1e-3
RELIEF_CRACK_CONDUCTANCE = 2e-12
#: Rod-side hydraulics (not in the parameters file): dead volume of the rod port and its line to
#: the tank [m^3], line conductance [m^3/(s Pa)] (0.15 MPa at the full rod-side flow), and the
#: range of the elastic tank's pressure [Pa], drawn uniformly.
ROD_DEAD_VOLUME = 1.0e-5
LINE_CONDUCTANCE = 1.0e-10
TANK_PRESSURE_RANGE = (0.1e6, 0.3e6)
#: Range of the motor speed loop's damping ratio; w_m = 2 zeta / tau keeps the low-frequency
#: lag of the first-order loop of time constant tau the parameters file states.
MOTOR_DAMPING_RANGE = (0.6, 0.9)
#: Controller gains.
KP = 20e3
KI = 40e3
#: Sensor ranges and quanta: a -0.1..25 MPa transducer on a 12-bit ADC; motor speed from
#: encoder counts (4096 per revolution) over 1 ms; a load cell read to 0.25 N.
PRESSURE_RANGE = (-0.1e6, 25e6)
PRESSURE_QUANTUM = (PRESSURE_RANGE[1] - PRESSURE_RANGE[0]) / 4095.0
MOTOR_SPEED_QUANTUM = 2.0 * math.pi / (4096 * 1e-3)
LOAD_FORCE_QUANTUM = 0.25
NOISE_RANGES: dict[str, tuple[float, float]] = {
    'position_std': (2e-6, 8e-6),
    'position_quantum': (1e-6, 5e-6),
    'pressure_std': (10e3, 30e3),
    'motor_speed_std': (0.5, 1.5),
    'load_force_std': (1.0, 5.0),
}

_EFFECT_IDS = {name: index for index, name in enumerate(EFFECT_CHOICES)}
_N_SINES = 8
_N_STRIDE_FACTORS = 64


def nominal_plant(joint_type: str, load_mass: float = 50.0,
                  rig: Path | None = None) -> dict[str, float]:
    """Give the plant constants as the parameters file states them (nuisances at nominal).

    Parameters
    ----------
    joint_type : str
        ``'hip'`` or ``'knee'``.
    load_mass : float
        Load mass M_L moved with the piston [kg].
    rig : Path or None
        Folder of the parameters files (default: the bench's, test/rigs.py).

    Returns
    -------
    dict of str to float
        Every constant the simulation needs, SI.

    """
    params = rig_parameters(joint_type, rig)
    area_a = math.pi / 4.0 * params.bore_diameter**2
    area_b = math.pi / 4.0 * (params.bore_diameter**2 - params.rod_diameter**2)
    zeta = 0.75
    return {
        'pump_displacement': params.pump_displacement,
        'flow_gain': 1.0,
        'pump_leakage': params.pump_leakage,
        'bulk_modulus': params.bulk_modulus,
        'dead_volume': params.dead_volume,
        'area_a': area_a,
        'area_b': area_b,
        'rod_dead_volume': ROD_DEAD_VOLUME,
        'stroke': params.stroke,
        'mass': params.piston_mass + load_mass,
        'load_mass': load_mass,
        'damping': params.damping,
        'tank_pressure': 0.15e6,
        'line_conductance': LINE_CONDUCTANCE,
        'motor_time_constant': params.motor_time_constant,
        'motor_damping_ratio': zeta,
        'motor_natural_frequency': 2.0 * zeta / params.motor_time_constant,
        'motor_speed_max': params.motor_speed_max,
        'relief_pressure': params.relief_pressure,
        'relief_conductance': params.relief_conductance,
        'cavitation_pressure': params.cavitation_pressure,
        'end_stop_stiffness': params.end_stop_stiffness,
        'end_stop_damping': params.end_stop_damping,
    }


_CONSTANT_NAMES = (
    'pump_displacement',
    'flow_gain',
    'pump_leakage',
    'bulk_modulus',
    'dead_volume',
    'area_a',
    'area_b',
    'rod_dead_volume',
    'stroke',
    'mass',
    'damping',
    'tank_pressure',
    'line_conductance',
    'motor_natural_frequency',
    'motor_damping_ratio',
    'motor_speed_max',
    'relief_pressure',
    'relief_conductance',
    'cavitation_pressure',
    'end_stop_stiffness',
    'end_stop_damping',
)


@njit(cache=True)
def effective_bulk_modulus(pressure: float, bulk_modulus: float, air: float) -> float:
    """Tangent bulk modulus of oil with a free air fraction compressed adiabatically.

    Parameters
    ----------
    pressure : float
        Gauge pressure [Pa].
    bulk_modulus : float
        Bulk modulus of the oil (and hoses) [Pa].
    air : float
        Free air volume fraction at atmospheric pressure, alpha0 [-]; 0 gives the oil alone.

    Returns
    -------
    float
        E_eff = (V_oil + V_air) / (V_oil / E + V_air / (1.4 p_abs)) [Pa], with
        V_air = alpha0 (p_atm / p_abs)^(1 / 1.4) and V_oil = 1 - alpha0.

    """
    if air <= 0.0:
        return bulk_modulus
    p_abs = max(pressure + ATMOSPHERE, 1e3)
    v_air = air * (ATMOSPHERE / p_abs) ** (1.0 / POLYTROPIC_EXPONENT)
    v_oil = 1.0 - air
    return float((v_oil + v_air) / (v_oil / bulk_modulus + v_air / (POLYTROPIC_EXPONENT * p_abs)))


@njit(cache=True)
def _pump_flow(n: float, p_a: float, c: FloatArray, effect: int, size: float) -> float:
    """Flow of the pump into chamber A, net of its leakage [m^3/s]."""
    n_eff = n
    if effect == 2:  # pump_deadzone
        if abs(n) > size:
            n_eff = n - size * math.copysign(1.0, n)
        else:
            n_eff = 0.0
    flow = c[0] * c[1] * n_eff - c[2] * p_a
    if effect == 4:  # quadratic_leakage
        flow -= size * p_a * abs(p_a)
    return float(flow)


@njit(cache=True)
def _relief_flow(p_a: float, c: FloatArray, effect: int, size: float) -> float:
    """Flow out of chamber A through the safety valve [m^3/s]."""
    flow = 0.0
    if p_a > c[16]:
        flow += c[17] * (p_a - c[16])
    if effect == 5 and p_a > size:  # relief_valve
        flow += RELIEF_CRACK_CONDUCTANCE * (min(p_a, c[16]) - size)
    return flow


@njit(cache=True)
def _derivatives(
    s: FloatArray, u: float, force: float, c: FloatArray, effect: int, size: float, d: FloatArray
) -> None:
    """Write the time derivative of the state s = (x, v, p_A, p_B, n, w) into d."""
    x, v, p_a, p_b, n, w = s[0], s[1], s[2], s[3], s[4], s[5]
    area_a, area_b, stroke = c[5], c[6], c[8]
    air = size if effect == 6 else 0.0
    # Chamber A.
    volume_a = c[4] + area_a * max(x, 0.0)
    capacity_a = volume_a / effective_bulk_modulus(p_a, c[3], air)
    dp_a = (_pump_flow(n, p_a, c, effect, size) - area_a * v - _relief_flow(p_a, c, effect, size))
    dp_a /= capacity_a
    if p_a <= c[18] and dp_a < 0.0:
        dp_a = 0.0
    # Rod side B, through the valve and a line to the elastic tank.
    volume_b = c[7] + area_b * max(stroke - x, 0.0)
    dp_b = (area_b * v - c[12] * (p_b - c[11])) * c[3] / volume_b
    if p_b <= c[18] and dp_b < 0.0:
        dp_b = 0.0
    # Piston and load.
    f = area_a * p_a - area_b * p_b - c[10] * v - force
    if effect == 1:  # coulomb_friction
        f -= size * math.tanh(v / FRICTION_VELOCITY)
    if x < 0.0:
        f -= c[19] * x + c[20] * v
    elif x > stroke:
        f -= c[19] * (x - stroke) + c[20] * v
    # Motor speed loop, second order.
    wm, zeta, n_max = c[13], c[14], c[15]
    dn = w
    dw = wm * wm * (u - n) - 2.0 * zeta * wm * w
    if (n >= n_max and dn > 0.0) or (n <= -n_max and dn < 0.0):
        dn = 0.0
        dw = min(dw, 0.0) if n > 0.0 else max(dw, 0.0)
    d[0] = v
    d[1] = f / c[9]
    d[2] = dp_a
    d[3] = dp_b
    d[4] = dn
    d[5] = dw


@njit(cache=True)
def _rk4(
    s: FloatArray,
    u: float,
    f0: float,
    f1: float,
    h: float,
    steps: int,
    c: FloatArray,
    effect: int,
    size: float,
) -> None:
    """Advance s by ``steps`` RK4 steps of h, the load going linearly from f0 to f1."""
    k1 = np.empty(6)
    k2 = np.empty(6)
    k3 = np.empty(6)
    k4 = np.empty(6)
    tmp = np.empty(6)
    df = (f1 - f0) / steps
    for i in range(steps):
        fa = f0 + df * i
        fm = fa + 0.5 * df
        fb = fa + df
        _derivatives(s, u, fa, c, effect, size, k1)
        for j in range(6):
            tmp[j] = s[j] + 0.5 * h * k1[j]
        _derivatives(tmp, u, fm, c, effect, size, k2)
        for j in range(6):
            tmp[j] = s[j] + 0.5 * h * k2[j]
        _derivatives(tmp, u, fm, c, effect, size, k3)
        for j in range(6):
            tmp[j] = s[j] + h * k3[j]
        _derivatives(tmp, u, fb, c, effect, size, k4)
        for j in range(6):
            s[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        # Pressure floor (cavitation) and motor speed limit.
        s[2] = max(s[2], c[18])
        s[3] = max(s[3], c[18])
        if s[4] > c[15]:
            s[4] = c[15]
            s[5] = min(s[5], 0.0)
        elif s[4] < -c[15]:
            s[4] = -c[15]
            s[5] = max(s[5], 0.0)


@njit(cache=True)
def _run(
    c: FloatArray,
    effect: int,
    size: float,
    reference: FloatArray,
    reference_velocity: FloatArray,
    load: FloatArray,
    position_noise: FloatArray,
    position_quantum: float,
    command: FloatArray,
    open_loop: bool,
    gains: FloatArray,
    state0: FloatArray,
    integral0: float,
    command0: float,
    period: float,
    substeps: int,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Simulate the closed (or open) loop; give states, commands and measured positions."""
    count = reference.shape[0]
    states = np.empty((count, 6))
    commands = np.empty(count)
    measured = np.empty(count)
    s = state0.copy()
    integral = integral0
    kff, kp, ki = gains[0], gains[1], gains[2]
    n_max = c[15]
    delay = size if effect == 3 else 0.0
    whole = math.floor(delay / period + 1e-12)
    fraction = delay - whole * period
    if fraction < 1e-12 * period:
        fraction = 0.0
    first = 0
    if fraction > 0.0:
        first = max(1, round(substeps * fraction / period))
        first = min(first, substeps - 1)
    for k in range(count):
        states[k, :] = s
        x_meas = s[0] + position_noise[k]
        if position_quantum > 0.0:
            x_meas = position_quantum * math.floor(x_meas / position_quantum + 0.5)
        measured[k] = x_meas
        if open_loop:
            u = command[k]
        else:
            error = reference[k] - x_meas
            u = kff * reference_velocity[k] + kp * error + ki * integral
            if u > n_max:
                u = n_max
            elif u < -n_max:
                u = -n_max
            else:
                integral += error * period
        commands[k] = u
        if k == count - 1:
            break
        f0 = load[k]
        f1 = load[k + 1]
        # Command the motor sees: the one sent `delay` earlier.
        j_new = k - whole
        u_new = commands[j_new] if j_new >= 0 else command0
        if first == 0:
            _rk4(s, u_new, f0, f1, period / substeps, substeps, c, effect, size)
        else:
            j_old = j_new - 1
            u_old = commands[j_old] if j_old >= 0 else command0
            f_mid = f0 + (f1 - f0) * fraction / period
            _rk4(s, u_old, f0, f_mid, fraction / first, first, c, effect, size)
            rest = substeps - first
            _rk4(s, u_new, f_mid, f1, (period - fraction) / rest, rest, c, effect, size)
    return states, commands, measured


def _constants(plant: Mapping[str, float]) -> FloatArray:
    return np.array([float(plant[name]) for name in _CONSTANT_NAMES])


def hold_motor_speed(
    plant: Mapping[str, float], pressure_a: float, effect: str = 'none', size: float = 0.0
) -> float:
    """Motor speed whose pump flow just balances leakage and relief at a chamber pressure.

    Parameters
    ----------
    plant : mapping of str to float
        Plant constants (``nominal_plant`` or ``Draw.plant``).
    pressure_a : float
        Rodless chamber pressure [Pa].
    effect : str
        Hidden effect.
    size : float
        Its size.

    Returns
    -------
    float
        n [rad/s].

    """
    loss = plant['pump_leakage'] * pressure_a
    if effect == 'quadratic_leakage':
        loss += size * pressure_a * abs(pressure_a)
    if pressure_a > plant['relief_pressure']:
        loss += plant['relief_conductance'] * (pressure_a - plant['relief_pressure'])
    if effect == 'relief_valve' and pressure_a > size:
        loss += RELIEF_CRACK_CONDUCTANCE * (min(pressure_a, plant['relief_pressure']) - size)
    n = loss / (plant['pump_displacement'] * plant['flow_gain'])
    if effect == 'pump_deadzone' and n != 0.0:
        n += math.copysign(size, n)
    return n


def simulate(
    plant: Mapping[str, float],
    reference: FloatArray,
    reference_velocity: FloatArray,
    load_force: FloatArray,
    *,
    effect: str = 'none',
    size: float = 0.0,
    position_noise: FloatArray | None = None,
    position_quantum: float = 0.0,
    command: FloatArray | None = None,
    initial_position: float | None = None,
    initial_motor_speed: float | None = None,
    substeps: int = SUBSTEPS,
) -> dict[str, FloatArray]:
    """Simulate the plant at 200 Hz samples, in closed loop or on a given command.

    The plant starts at rest at the first reference sample (or ``initial_position``), with the
    chamber pressure that holds the first load sample, the rod side at the tank pressure and the
    motor at the speed that holds that pressure (or ``initial_motor_speed``); the controller's
    integral starts at the value that commands that speed.

    Parameters
    ----------
    plant : mapping of str to float
        Plant constants (``nominal_plant`` or ``Draw.plant``).
    reference, reference_velocity, load_force : numpy.ndarray
        Position reference [m], its derivative [m/s] and the load force [N] at the samples.
    effect : str
        Hidden effect, one of ``EFFECT_CHOICES``.
    size : float
        Its size (SI).
    position_noise : numpy.ndarray, optional
        Noise added to the position before quantisation, at the samples [m]; default none.
    position_quantum : float
        Quantum of the position sensor [m]; 0 for none.
    command : numpy.ndarray, optional
        Motor speed command per sample [rad/s]; given, the loop is open (no controller).
    initial_position, initial_motor_speed : float, optional
        Initial position [m] and motor speed [rad/s].
    substeps : int
        RK4 steps per sample.

    Returns
    -------
    dict of str to numpy.ndarray
        The noise-free ``COLUMNS`` (``position`` is the true one), plus
        ``reference_velocity``, ``velocity``, ``measured_position`` (what the controller read)
        and ``motor_acceleration``.

    """
    if effect not in _EFFECT_IDS:
        raise ValueError(f'unknown effect {effect!r}; expected one of {EFFECT_CHOICES}')
    reference = np.ascontiguousarray(reference, dtype=float)
    count = reference.shape[0]
    reference_velocity = np.ascontiguousarray(reference_velocity, dtype=float)
    load_force = np.ascontiguousarray(load_force, dtype=float)
    noise = np.zeros(count) if position_noise is None else np.asarray(position_noise, float)
    x0 = float(reference[0]) if initial_position is None else initial_position
    p_b0 = plant['tank_pressure']
    p_a0 = (float(load_force[0]) + plant['area_b'] * p_b0) / plant['area_a']
    n0 = hold_motor_speed(plant, p_a0, effect, size)
    if initial_motor_speed is not None:
        n0 = initial_motor_speed
    kff = plant['area_a'] / plant['pump_displacement']  # the nominal flow gain
    gains = np.array([kff, KP, KI])
    integral0 = (n0 - kff * float(reference_velocity[0])) / KI
    state0 = np.array([x0, 0.0, p_a0, p_b0, n0, 0.0])
    open_loop = command is not None
    commands = np.zeros(count) if command is None else np.asarray(command, dtype=float)
    states, sent, measured = _run(
        _constants(plant),
        _EFFECT_IDS[effect],
        float(size),
        reference,
        reference_velocity,
        load_force,
        np.ascontiguousarray(noise),
        float(position_quantum),
        np.ascontiguousarray(commands),
        open_loop,
        gains,
        state0,
        float(integral0),
        float(n0),
        PERIOD,
        int(substeps),
    )
    return {
        'time': np.arange(count) * PERIOD,
        'motor_speed_command': sent,
        'position': states[:, 0],
        'reference': reference.copy(),
        'reference_velocity': reference_velocity.copy(),
        'pressure_a': states[:, 2],
        'pressure_b': states[:, 3],
        'motor_speed': states[:, 4],
        'load_force': load_force.copy(),
        'velocity': states[:, 1],
        'measured_position': measured,
        'motor_acceleration': states[:, 5],
    }


@dataclass(frozen=True)
class Draw:
    """One simulated experiment: its hidden truth and its measured data.

    Attributes
    ----------
    seed : int
        Seed of ``numpy.random.default_rng`` it was drawn from.
    effect : str
        Hidden effect, one of ``EFFECT_CHOICES``.
    size : float
        Its size (SI); 0 for ``'none'``.
    joint_type : str
        ``'hip'`` or ``'knee'``.
    excitation : str
        One of ``EXCITATIONS``.
    parameters : dict of str to float
        Drawn values of the nuisance parameters (keys of ``NUISANCE_SPREADS``).
    noise : dict of str to float
        Standard deviations and quanta of the sensors.
    period : float
        Sample period [s].
    columns : dict of str to numpy.ndarray
        Measured data, keys ``COLUMNS``.
    clean : dict of str to numpy.ndarray
        Noise-free signals (``simulate``'s result).
    plant : dict of str to float
        Every plant constant used, drawn ones included.
    excitation_parameters : dict of str to float
        Scalars of the reference and load profile.

    """

    seed: int
    effect: str
    size: float
    joint_type: str
    excitation: str
    parameters: dict[str, float]
    noise: dict[str, float]
    period: float
    columns: dict[str, FloatArray]
    clean: dict[str, FloatArray]
    plant: dict[str, float] = field(default_factory=dict)
    excitation_parameters: dict[str, float] = field(default_factory=dict)

    @property
    def effects(self) -> dict[str, float]:
        """Give the hidden effect as ``{name: size}``, or ``{}`` for none."""
        return {} if self.effect == 'none' else {self.effect: self.size}


def effect_size(effect: str, u: float) -> float:
    """Map a uniform variate in [0, 1) to the effect's size range.

    Parameters
    ----------
    effect : str
        Effect name (not ``'none'``).
    u : float
        Uniform variate.

    Returns
    -------
    float
        Size: log-uniform in ``EFFECT_RANGES``, linear for the relief valve.

    """
    lo, hi = EFFECT_RANGES[effect]
    if effect == 'relief_valve':
        return lo + (hi - lo) * u
    return float(lo * (hi / lo) ** u)


def noise_std(noise: Mapping[str, float], column: str) -> float:
    """Give the total standard deviation (noise and quantisation) of a measured column.

    Parameters
    ----------
    noise : mapping of str to float
        ``Draw.noise``.
    column : str
        ``'position'``, ``'pressure_a'``, ``'pressure_b'``, ``'motor_speed'`` or
        ``'load_force'``.

    Returns
    -------
    float
        sqrt(sigma^2 + q^2 / 12).

    """
    key = 'pressure' if column.startswith('pressure') else column
    return math.hypot(noise[f'{key}_std'], noise[f'{key}_quantum'] / math.sqrt(12.0))


def _window(t: FloatArray, ramp: float) -> tuple[FloatArray, FloatArray]:
    """Give a smooth 0-to-1 ramp over [0, ramp] and its derivative."""
    phase = np.clip(t / ramp, 0.0, 1.0)
    w = 0.5 * (1.0 - np.cos(np.pi * phase))
    dw = np.where(t < ramp, 0.5 * np.pi / ramp * np.sin(np.pi * phase), 0.0)
    return w, dw


def _sine_sum(
    t: FloatArray, centre: float, values: FloatArray, scale: float = 1.0
) -> tuple[FloatArray, FloatArray, dict[str, float]]:
    """Sum of sines, one per log band of 0.2-5 Hz, amplitude ~ 1/f, ramped in over 1.5 s.

    ``scale`` multiplies every amplitude and velocity (:func:`rigs.motion_scale`).
    """
    u_freq, u_phase, u_amp = values[:_N_SINES], values[_N_SINES : 2 * _N_SINES], values[-1]
    edges = np.geomspace(0.2, 5.0, _N_SINES + 1)
    freqs = edges[:-1] * (edges[1:] / edges[:-1]) ** u_freq
    phases = 2.0 * np.pi * u_phase
    total = scale * (0.015 + 0.007 * u_amp)  # sum of amplitudes [m]
    v_bound = scale * 0.09  # bound of the summed velocity amplitudes [m/s]
    scale = min(total / np.sum(1.0 / freqs), v_bound / (2.0 * np.pi * _N_SINES))
    amps = scale / freqs
    omega = 2.0 * np.pi * freqs
    arg = np.outer(t, omega) + phases
    signal = np.sin(arg) @ amps
    rate = np.cos(arg) @ (amps * omega)
    w, dw = _window(t, 1.5)
    info = {f'sine_{i}_frequency': float(f) for i, f in enumerate(freqs)}
    info |= {f'sine_{i}_amplitude': float(a) for i, a in enumerate(amps)}
    return centre + w * signal, w * rate + dw * signal, info


_GAIT_SHAPES = {
    # Harmonic amplitudes and phases of a stride-like stroke, hip- and knee-like.
    'hip': ((1.0, 0.0), (0.16, 0.6), (0.05, 1.4), (0.02, 2.0)),
    'knee': ((1.0, 0.0), (0.45, -0.9), (0.12, 0.5), (0.04, 1.1)),
}


def _gait(
    t: FloatArray, joint_type: str, centre: float, values: FloatArray, scale: float = 1.0
) -> tuple[FloatArray, FloatArray, float, dict[str, float]]:
    """Periodic stride-like stroke: a few harmonics of the stride, ramped in over 1.5 s.

    ``scale`` multiplies the excursion and the velocity bound (:func:`rigs.motion_scale`).
    """
    stride = 1.3 + 0.4 * values[0]
    peak_to_peak = scale * (0.030 + 0.010 * values[1])
    jitter = 0.3 * (values[2:6] - 0.5)
    omega = 2.0 * np.pi / stride
    shape = np.zeros_like(t)
    rate = np.zeros_like(t)
    fine = np.linspace(0.0, stride, 2001)
    fine_shape = np.zeros_like(fine)
    for h, ((amp, phase), dphi) in enumerate(zip(_GAIT_SHAPES[joint_type], jitter, strict=True)):
        k = h + 1
        shape += amp * np.cos(k * omega * t + phase + dphi)
        rate -= amp * k * omega * np.sin(k * omega * t + phase + dphi)
        fine_shape += amp * np.cos(k * omega * fine + phase + dphi)
    fine_rate = np.gradient(fine_shape, fine)
    gain = min(peak_to_peak / float(np.ptp(fine_shape)),
               scale * 0.1 / float(np.max(np.abs(fine_rate))))
    w, dw = _window(t, 1.5)
    info = {'stride_period': stride, 'stroke_peak_to_peak': gain * float(np.ptp(fine_shape))}
    return centre + gain * w * shape, gain * (w * rate + dw * shape), stride, info


def _double_hump(s: FloatArray) -> FloatArray:
    """Give the stance load shape over the stance phase s in [0, 1]: two humps, 0 at the ends."""
    humps = np.exp(-(((s - 0.25) / 0.13) ** 2)) + 0.85 * np.exp(-(((s - 0.75) / 0.13) ** 2))
    return humps * np.sin(np.pi * s) ** 0.5


def _load_profile(
    t: FloatArray,
    excitation: str,
    stride: float,
    area_a: float,
    area_b: float,
    tank_pressure: float,
    load_mass: float,
    values: FloatArray,
    stride_factors: FloatArray,
) -> tuple[FloatArray, dict[str, float]]:
    """Load force [N]: the weight m g of the load mass plus a profile dF(t).

    The sum runs between a low level (the wearer partly unloads the mass) and a high one, set
    by the static chamber pressures they need: 2-3 MPa and 12.2-13 MPa, so the relief valve's
    crack (8-11 MPa) is always exceeded and the 18 MPa setting never reached.

    """
    p_low = 2.0e6 + 1.0e6 * values[0]
    p_high = 12.2e6 + 0.8e6 * values[1]
    f_low = p_low * area_a - area_b * tank_pressure
    f_high = p_high * area_a - area_b * tank_pressure
    weight = load_mass * GRAVITY
    if excitation == 'sine_sum':
        bump_rate = 0.3 + 0.3 * values[2]  # [Hz]
        phase = np.pi * values[3]
        bump = np.sin(np.pi * bump_rate * t + phase) ** 4
        slow = 0.5 * (1.0 + np.sin(2.0 * np.pi * (0.05 + 0.07 * values[4]) * t))
        level = 0.3 * slow * (1.0 - bump)  # between bumps: partly loaded
        profile = level + bump
    else:
        # Stance (60 % of the stride): a double hump; swing: the low level.
        phi = np.mod(t / stride + values[3], 1.0)
        index = np.floor(t / stride + values[3]).astype(int) % stride_factors.size
        s = np.clip(phi / 0.6, 0.0, 1.0)
        hump = _double_hump(s) * (phi < 0.6)
        peak = float(np.max(_double_hump(np.linspace(0.0, 1.0, 4001))))
        profile = hump / peak * stride_factors[index]
    force = f_low + (f_high - f_low) * profile
    info = {'load_low': f_low, 'load_high': f_high, 'load_weight': weight}
    return force, info


def _quantise(values: FloatArray, quantum: float) -> FloatArray:
    return quantum * np.round(values / quantum)


def draw(
    seed: int,
    joint_type: str | None = None,
    *,
    effect: str | None = None,
    size: float | None = None,
    excitation: str | None = None,
    duration: float = 30.0,
    load_mass: float = 50.0,
    rig: Path | None = None,
) -> Draw:
    """Draw one experiment from a seed and simulate it.

    Every variate comes from ``numpy.random.default_rng(seed)``, drawn in a fixed order
    whatever is forced, so forcing one choice leaves the others unchanged.

    Parameters
    ----------
    seed : int
        Seed.
    joint_type : str, optional
        ``'hip'`` or ``'knee'``; drawn if not given.
    effect : str, optional
        One of ``EFFECT_CHOICES``; drawn (uniformly) if not given.
    size : float, optional
        Effect size (SI); drawn in ``EFFECT_RANGES`` if not given.
    excitation : str, optional
        One of ``EXCITATIONS``; drawn if not given.
    duration : float
        Length of the record [s].
    load_mass : float
        Load mass [kg].
    rig : Path or None
        Folder of the parameters files to draw around (default: the bench's, test/rigs.py;
        e.g. ``rigs.SHIPPED_DIR``); the excitation shrinks with its stroke
        (:func:`rigs.motion_scale`), the load keeps its pressures.

    Returns
    -------
    Draw
        The experiment.

    """
    rng = np.random.default_rng(seed)
    u_joint = int(rng.integers(len(JOINT_TYPES)))
    u_effect = int(rng.integers(len(EFFECT_CHOICES)))
    u_size = float(rng.random())
    u_excitation = int(rng.integers(len(EXCITATIONS)))
    u_nuisance = rng.random(len(NUISANCE_SPREADS))
    u_zeta, u_tank = rng.random(2)
    u_noise = rng.random(len(NOISE_RANGES))
    u_centre = float(rng.random())
    u_load = rng.random(5)
    u_sines = rng.random(2 * _N_SINES + 1)
    u_gait = rng.random(6)
    stride_factors = 0.97 + 0.03 * rng.random(_N_STRIDE_FACTORS)
    count = round(duration * RATE) + 1
    z = rng.standard_normal((5, count))

    joint_type = JOINT_TYPES[u_joint] if joint_type is None else joint_type
    if joint_type not in JOINT_TYPES:
        raise ValueError(f'unknown joint type {joint_type!r}')
    effect = EFFECT_CHOICES[u_effect] if effect is None else effect
    if effect not in EFFECT_CHOICES:
        raise ValueError(f'unknown effect {effect!r}; expected one of {EFFECT_CHOICES}')
    if effect == 'none':
        if size:
            raise ValueError('effect none takes no size')
        size = 0.0
    elif size is None:
        size = effect_size(effect, u_size)
    excitation = EXCITATIONS[u_excitation] if excitation is None else excitation
    if excitation not in EXCITATIONS:
        raise ValueError(f'unknown excitation {excitation!r}; expected one of {EXCITATIONS}')

    plant = nominal_plant(joint_type, load_mass, rig)
    scale = motion_scale(joint_type, rig)
    parameters = {}
    for (name, spread), u in zip(NUISANCE_SPREADS.items(), u_nuisance, strict=True):
        parameters[name] = plant[name] * (1.0 + spread * (2.0 * u - 1.0))
    plant.update(parameters)
    zeta = MOTOR_DAMPING_RANGE[0] + (MOTOR_DAMPING_RANGE[1] - MOTOR_DAMPING_RANGE[0]) * u_zeta
    plant['motor_damping_ratio'] = zeta
    plant['motor_natural_frequency'] = 2.0 * zeta / plant['motor_time_constant']
    plant['tank_pressure'] = TANK_PRESSURE_RANGE[0] + (
        TANK_PRESSURE_RANGE[1] - TANK_PRESSURE_RANGE[0]
    ) * float(u_tank)
    noise = {
        name: lo + (hi - lo) * float(u)
        for (name, (lo, hi)), u in zip(NOISE_RANGES.items(), u_noise, strict=True)
    }
    noise['pressure_quantum'] = PRESSURE_QUANTUM
    noise['motor_speed_quantum'] = MOTOR_SPEED_QUANTUM
    noise['load_force_quantum'] = LOAD_FORCE_QUANTUM

    t: FloatArray = np.arange(count, dtype=np.float64) * PERIOD
    centre = 0.5 * plant['stroke'] + scale * 0.010 * (u_centre - 0.5)
    if excitation == 'sine_sum':
        reference, reference_velocity, info = _sine_sum(t, centre, u_sines, scale)
        stride = 0.0
    else:
        reference, reference_velocity, stride, info = _gait(t, joint_type, centre, u_gait, scale)
    load, load_info = _load_profile(
        t,
        excitation,
        stride,
        plant['area_a'],
        plant['area_b'],
        plant['tank_pressure'],
        load_mass,
        u_load,
        stride_factors,
    )
    info |= load_info

    clean = simulate(
        plant,
        reference,
        reference_velocity,
        load,
        effect=effect,
        size=size,
        position_noise=noise['position_std'] * z[0],
        position_quantum=noise['position_quantum'],
    )
    low, high = PRESSURE_RANGE

    def pressure(values: FloatArray, normal: FloatArray) -> FloatArray:
        read = low + _quantise(values - low + noise['pressure_std'] * normal, PRESSURE_QUANTUM)
        return np.clip(read, low, high)

    columns = {
        'time': clean['time'].copy(),
        'motor_speed_command': clean['motor_speed_command'].copy(),
        'position': clean['measured_position'].copy(),
        'reference': reference.copy(),
        'pressure_a': pressure(clean['pressure_a'], z[1]),
        'pressure_b': pressure(clean['pressure_b'], z[2]),
        'motor_speed': _quantise(
            clean['motor_speed'] + noise['motor_speed_std'] * z[3], MOTOR_SPEED_QUANTUM
        ),
        'load_force': _quantise(load + noise['load_force_std'] * z[4], LOAD_FORCE_QUANTUM),
    }
    return Draw(
        seed=seed,
        effect=effect,
        size=float(size),
        joint_type=joint_type,
        excitation=excitation,
        parameters=parameters,
        noise=noise,
        period=PERIOD,
        columns=columns,
        clean=clean,
        plant=plant,
        excitation_parameters=info,
    )


def write_csv(draw: Draw, path: str | Path) -> None:
    """Write the measured data of a draw as CSV: a header row of ``COLUMNS``, then the samples.

    Parameters
    ----------
    draw : Draw
        The experiment.
    path : str or pathlib.Path
        File to write.

    """
    data = np.column_stack([draw.columns[name] for name in COLUMNS])
    with Path(path).open('w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        writer.writerows([[f'{value:.17g}' for value in row] for row in data])
