"""A third, independent truth plant: a simulated electro-hydraulic actuator (EHA) test rig.

A 24 V motor drives a one-way gear pump; a 4/2 solenoid valve routes its outlet to chamber A
(extend) or B (retract) and the other chamber to a gas accumulator, which is also the pump's
inlet (a closed circuit: no tank). A hydraulic load cylinder brakes the rod in both directions.
Written from the rig's physics only, to test a model-error diagnosis against a plant it has not
seen. All pressures are gauge [Pa], flows [m^3/s], SI throughout.

Equations (state x, v, z_A, z_B, z_P, m_acc, n, I, s)::

    geometry   A_A = pi D^2 / 4, A_B = A_A - pi d^2 / 4, V_A = V_A0 + A_A x,
               V_B = V_B0 + A_B (L - x)
    command    u_k = k_ff(v*) v*_k + k_p (x*_k - x_k,meas), |u_k| <= n_max, held over a sample;
               valve side c_k = sign(u_k), kept while |u_k| < u_db; n* = |u|, both acting
               tau_d later ('transport_delay', else 0)
    motor      J dn/dt = T_m - T_P - b_m n,  n >= 0 (one-way)
               T_m = clip(K_p (beta n* - n) + I, -0.1 T_max, T_max),
               dI/dt = K_i (n* - n), frozen while T_m is clipped and the error pushes further
               T_P = D_P dp_P / eta_m  (D_P dp_P eta_m if dp_P < 0),  dp_P = p_P - p_acc
    pump       q_P = D_P max(n - n_dz, 0) - L_P dp_P - L_2 dp_P |dp_P|
    valve      tau_v ds/dt = c - s;  openings a_PA = a_BT = max(s, 0), a_PB = a_AT = max(-s, 0)
               q_ij = K a_ij dp / (dp^2 + p_t^2)^(1/4)  (square-root orifice, laminar near 0)
    relief     q_R = G_R max(dp_P - p_set, 0) + G_c max(min(dp_P, p_set) - p_c, 0)
               (pump outlet to accumulator; the second term only for 'relief_valve')
    leakage    q_L = L_c (p_A - p_B)  (across the piston)
    nodes      oil content m (volume at atmospheric pressure) of a node of volume V:
               m = (V - V_g(p)) exp(p / E),  V_g = V_g0 (p_atm / (p + p_atm))^(1/gamma), so
               dz/dt = (exp(-p/E) q_in - dV/dt) / ((V - V_g) / E + V_g / (gamma (p + p_atm)))
               with p = z; below the cavitation floor p = p_cav and the node holds vapour
               C_v (p_cav - z): dz/dt = (exp(-p_cav/E) q_in - dV/dt) / C_v.
               q_in: P: q_P - q_PA - q_PB - q_R;  A: q_PA - q_AT - q_L;  B: q_PB - q_BT + q_L.
               V_g0 = 0 but for 'entrained_air' (chambers A and B only)
    accumulator dm_acc/dt = q_AT + q_BT + q_R - q_P,
               p_acc + p_atm = (p_0 + p_atm) (V_0 / (V_0 - m_acc))^kappa
    mechanics  M dv/dt = A_A p_A - A_B p_B - B v - F_brake - F_c tanh(v / v_c) + F_stop
               F_brake = F_b tanh(v / v_b) + c_b v  (load cylinder through a relief valve and a
               throttle); F_stop a spring-damper beyond 0 and L
    sensors    x: noise + 1 um resolution; p_A, p_B: noise, 12-bit over 0-25 MPa, clipped;
               motor speed: c_k n + noise; load cell: F_brake + m_load dv/dt + noise

The oil contents make the circuit conserve oil exactly: m_A + m_B + m_P + m_acc is constant.
"""

from __future__ import annotations

import csv
import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

EFFECTS = ('coulomb_friction', 'pump_deadzone', 'transport_delay', 'quadratic_leakage',
           'relief_valve', 'entrained_air')
EFFECT_CHOICES = ('none', *EFFECTS)
EXCITATIONS = ('sine_sum', 'steps')
COLUMNS = ('time', 'motor_speed_command', 'position', 'reference', 'pressure_a', 'pressure_b',
           'motor_speed', 'load_force')
RATE = 200.0  # default sample rate [Hz]

# RK4 substeps per sample. The stiffest modes are the brake's low-speed slope F_b / (v_b M)
# (<= 1.8e5 1/s with the drawn ranges and Coulomb friction) and the orifice-coupled pump-outlet
# and chamber pressures (g_0 E (1/V_P + 1/V_A) <= 1.1e5 1/s). At 200 Hz, 640 substeps give
# h = 7.8 us, |lambda h| <= 1.4: half RK4's stability limit of 2.79 on the real axis.
SUBSTEPS = 640

P_ATM = 101325.0  # atmospheric pressure [Pa]
MID_STROKE = 0.1  # where records start and excitations are centred [m]
PRE_ROLL = 1.0  # time the controller holds the start position before a record begins [s]

# Record-relative sizes of the two effects whose action depends on the record's pressures:
# the relief valve's crack pressure as a fraction of the record's high pump pressure
# difference, and the quadratic leakage as the fraction of a typical loaded pump flow it takes
# at that pressure.
RELIEF_CRACK_FRACTION = (0.3, 0.7)
QUADRATIC_LEAKAGE_FRACTION = (0.05, 0.3)
TYPICAL_LOADED_SPEED = 150.0  # motor speed at which a record's pump flow is judged [rad/s]
BRAKE_FORCE_RANGE = (1e3, 7e3)  # [N]


def datasheet() -> dict[str, float]:
    """Return what the rig's user knows: nominal values, SI.

    Returns
    -------
    dict of str to float
        Geometry, pump, motor, valve, accumulator, brake and mass values. Pressures are gauge;
        ``relief_pressure`` is the relief valve's setting as the pressure difference across it
        (pump outlet minus accumulator); ``motor_time_constant`` is the closed speed loop's
        equivalent first-order lag, unloaded and below the torque limit.
    """
    displacement = 1.6e-6 / (2.0 * math.pi)
    speed_max = 300.0
    efficiency = 0.85
    motor_damping = 2e-4
    inertia = 5e-5
    # The speed loop places its poles at -80 and -200 1/s and its set-point weight cancels the
    # slower one, so the unloaded loop is a first-order lag of 1/200 s.
    pole_slow, pole_fast = 80.0, 200.0
    return {
        'bore_diameter': 0.050,
        'rod_diameter': 0.028,
        'stroke': 0.2,
        'pump_displacement': displacement,
        'motor_speed_max': speed_max,
        # At 4 MPa and 150 rad/s the pump torque and the motor's friction take all of it.
        'motor_torque_peak': displacement * 4e6 / efficiency + motor_damping * 150.0,
        'pump_mechanical_efficiency': efficiency,
        'motor_time_constant': 1.0 / pole_fast,
        'motor_inertia': inertia,
        'motor_damping': motor_damping,
        'motor_speed_gain': inertia * (pole_slow + pole_fast),
        'motor_speed_integral_gain': inertia * pole_slow * pole_fast,
        'motor_setpoint_weight': pole_fast / (pole_slow + pole_fast),
        'charge_pressure': 0.75e6,
        'accumulator_volume': 0.32e-3,
        'accumulator_fill': 0.2,
        'polytropic_index': 1.3,
        'relief_pressure': 10e6,
        'relief_gain': displacement * speed_max / 0.3e6,
        'dead_volume_a': 25e-6,
        'dead_volume_b': 30e-6,
        'pump_outlet_volume': 12e-6,
        'bulk_modulus': 1.2e9,
        'pump_leakage': 7e-13,
        'cylinder_leakage': 1e-13,
        'damping': 1000.0,
        'piston_mass': 8.0,
        'load_mass': 32.0,
        'valve_time_constant': 0.015,
        'valve_pressure_drop': 0.25e6,
        'valve_rated_flow': displacement * speed_max,
        'brake_force': 4e3,
        'brake_velocity': 3.5e-3,
        'brake_damping': 3e3,
        'cavitation_pressure': -0.09e6,
        'pressure_sensor_range': 25e6,
    }


# Nuisance parameters drawn per record, in this order: name, low, high (SI). Datasheet values
# +-20-30 %; the charge pressure and the moving mass over the ranges the rig is used with.
_DS = datasheet()
_NUISANCE = (
    ('bulk_modulus', 0.75 * _DS['bulk_modulus'], 1.25 * _DS['bulk_modulus']),
    ('pump_leakage', 0.7 * _DS['pump_leakage'], 1.3 * _DS['pump_leakage']),
    ('damping', 0.7 * _DS['damping'], 1.3 * _DS['damping']),
    ('dead_volume_a', 0.75 * _DS['dead_volume_a'], 1.25 * _DS['dead_volume_a']),
    ('dead_volume_b', 0.75 * _DS['dead_volume_b'], 1.25 * _DS['dead_volume_b']),
    ('charge_pressure', 0.5e6, 1.0e6),
    ('accumulator_volume', 0.8 * _DS['accumulator_volume'], 1.2 * _DS['accumulator_volume']),
    ('motor_speed_gain', 0.75 * _DS['motor_speed_gain'], 1.25 * _DS['motor_speed_gain']),
    ('motor_speed_integral_gain', 0.75 * _DS['motor_speed_integral_gain'],
     1.25 * _DS['motor_speed_integral_gain']),
    ('motor_torque_peak', 0.8 * _DS['motor_torque_peak'], 1.2 * _DS['motor_torque_peak']),
    ('motor_inertia', 0.8 * _DS['motor_inertia'], 1.2 * _DS['motor_inertia']),
    ('motor_damping', 0.7 * _DS['motor_damping'], 1.3 * _DS['motor_damping']),
    ('valve_time_constant', 0.010, 0.020),
    ('valve_pressure_drop', 0.8 * _DS['valve_pressure_drop'], 1.2 * _DS['valve_pressure_drop']),
    ('brake_velocity', 0.7 * _DS['brake_velocity'], 1.3 * _DS['brake_velocity']),
    ('brake_damping', 0.7 * _DS['brake_damping'], 1.3 * _DS['brake_damping']),
    ('moving_mass', 20.0, 60.0),
    ('piston_mass', 0.75 * _DS['piston_mass'], 1.25 * _DS['piston_mass']),
    ('cylinder_leakage', 0.7 * _DS['cylinder_leakage'], 1.3 * _DS['cylinder_leakage']),
)

# Noise standard deviations drawn per record (name, low, high), then fixed resolutions.
_NOISE = (
    ('position', 2e-6, 5e-6),
    ('pressure', 10e3, 30e3),
    ('motor_speed', 0.5, 1.5),
    ('load_force', 10.0, 40.0),
)
POSITION_RESOLUTION = 1e-6  # [m]
PRESSURE_BITS = 12


def _area_a(ds: dict[str, float]) -> float:
    return math.pi * ds['bore_diameter'] ** 2 / 4.0


def _area_b(ds: dict[str, float]) -> float:
    return _area_a(ds) - math.pi * ds['rod_diameter'] ** 2 / 4.0


def _accumulator_pressure(stored: float, volume: float, charge: float, index: float) -> float:
    return (charge + P_ATM) * (volume / (volume - stored)) ** index - P_ATM


def high_pressure(parameters: dict[str, float]) -> float:
    """Return a record's typical high pump pressure difference [Pa].

    Retracting against the brake with chamber A at the accumulator's starting pressure needs
    ``(F_b + p_acc A_rod) / A_B`` across the pump: the largest steady pressure of the record,
    unless the motor's torque limit caps it first (at a creeping speed, taken as 30 rad/s).

    Parameters
    ----------
    parameters : dict of str to float
        A record's nuisance values (``Draw.parameters``).

    Returns
    -------
    float
        Pump outlet minus inlet pressure [Pa].
    """
    ds = _DS
    volume = parameters['accumulator_volume']
    p_acc = _accumulator_pressure(ds['accumulator_fill'] * volume, volume,
                                  parameters['charge_pressure'], ds['polytropic_index'])
    rod = _area_a(ds) - _area_b(ds)
    needed = (parameters['brake_force'] + p_acc * rod) / _area_b(ds)
    torque = parameters['motor_torque_peak'] - parameters['motor_damping'] * 30.0
    return min(needed, torque * ds['pump_mechanical_efficiency'] / ds['pump_displacement'])


def effect_range(effect: str, parameters: dict[str, float]) -> tuple[float, float]:
    """Return the size range [low, high] (SI) of an effect for one record.

    Most effects have a fixed range (``EFFECT_RANGES``). The relief valve's crack pressure and
    the quadratic leakage act only through the record's pressures, so their ranges follow the
    record's high pump pressure (``high_pressure``): the crack pressure spans 30-70 % of it,
    and the leakage takes 5-30 % of a loaded pump flow there.

    Parameters
    ----------
    effect : str
        One of ``EFFECTS``.
    parameters : dict of str to float
        The record's nuisance values.

    Returns
    -------
    tuple of float
        Low and high ends. The weaker end is ``low`` but for 'relief_valve' (a higher crack
        pressure leaks less).
    """
    if effect == 'relief_valve':
        dp = high_pressure(parameters)
        return RELIEF_CRACK_FRACTION[0] * dp, RELIEF_CRACK_FRACTION[1] * dp
    if effect == 'quadratic_leakage':
        dp = high_pressure(parameters)
        flow = _DS['pump_displacement'] * TYPICAL_LOADED_SPEED
        return (QUADRATIC_LEAKAGE_FRACTION[0] * flow / dp ** 2,
                QUADRATIC_LEAKAGE_FRACTION[1] * flow / dp ** 2)
    return _FIXED_RANGES[effect]


# Why these sizes: each moves the measured outputs many noise levels, yet is a plausible fault.
_FIXED_RANGES: dict[str, tuple[float, float]] = {
    # Seal friction of a 50 mm cylinder is 1.5-4 % of its 20 kN rating; 300 N shifts the
    # working chamber's pressure by 0.15-0.22 MPa (5-20 pressure noise levels) while it moves.
    'coulomb_friction': (300.0, 800.0),
    # 8 rad/s is 3 % of top speed, but it is the whole flow of a slow move and of the
    # leakage-holding speed at rest: it shows up at every reversal as a position lag.
    'pump_deadzone': (8.0, 40.0),
    # A bus and drive latency of 1.6-5 samples: it adds phase lag to the position loop and
    # shifts every reversal; below 8 ms a light-brake record hides it within 5 noise levels.
    'transport_delay': (0.008, 0.025),
    # Free air of 4-15 % of each chamber's mid-stroke volume, trapped in it (a poorly bled
    # cylinder): it softens the chambers 7-22 times at 1 MPa and 1.6-3.2 times at 4 MPa, so
    # every pressure build-up lags.
    'entrained_air': (0.04, 0.15),
}


def _pooled_ranges() -> dict[str, tuple[float, float]]:
    """Return each effect's range over all records (the union of the record ranges)."""
    ranges = dict(_FIXED_RANGES)
    # high_pressure is monotonic in each value, so the corners of the drawn box bound it.
    bounds = {name: (low, high) for name, low, high in _NUISANCE}
    bounds['brake_force'] = BRAKE_FORCE_RANGE
    names = ('charge_pressure', 'accumulator_volume', 'motor_torque_peak', 'motor_damping',
             'brake_force')
    extremes = [dict(zip(names, corner, strict=True))
                for corner in itertools.product(*(bounds[name] for name in names))]
    for effect in ('quadratic_leakage', 'relief_valve'):
        lows, highs = zip(*(effect_range(effect, p) for p in extremes), strict=True)
        ranges[effect] = (min(lows), max(highs))
    return {effect: ranges[effect] for effect in EFFECTS}


# The size range of each effect over all records, SI (see ``effect_range`` for one record's).
EFFECT_RANGES: dict[str, tuple[float, float]] = _pooled_ranges()

# Indices into the numba parameter vector.
(I_AREA_A, I_AREA_B, I_STROKE, I_VOL_A0, I_VOL_B0, I_VOL_P, I_BULK, I_DISP, I_LEAK, I_LEAK2,
 I_DEADZONE, I_EFF, I_INERTIA, I_MOTOR_DAMP, I_KP_N, I_KI_N, I_BETA, I_TORQUE_MAX, I_TORQUE_MIN,
 I_TAU_V, I_VALVE_K, I_P_LAMINAR, I_RELIEF_GAIN, I_RELIEF_SET, I_CRACK_GAIN, I_CRACK_P,
 I_CYL_LEAK, I_P_CAV, I_VOID_A, I_VOID_B, I_VOID_P, I_AIR_A, I_AIR_B, I_GAMMA, I_P_ATM,
 I_CHARGE, I_ACC_VOL, I_POLY, I_ACC_PORT, I_MASS, I_DAMPING, I_BRAKE_F, I_BRAKE_V, I_BRAKE_C,
 I_COULOMB, I_COULOMB_V, I_STOP_K, I_STOP_C, I_LOAD_MASS, I_KP_X, I_KFF_EXT, I_KFF_RET,
 I_SPEED_MAX, I_DEADBAND, I_POS_RES) = range(55)
N_PARAMS = 55

# State indices: mechanics, node pressures (or vapour), accumulator content, motor, spool, and
# the volumes passed so far along each flow path (for the oil balance).
(S_X, S_V, S_ZA, S_ZB, S_ZP, S_ACC, S_N, S_INT, S_SPOOL, S_VOL_PUMP, S_VOL_PA, S_VOL_PB,
 S_VOL_AT, S_VOL_BT, S_VOL_RELIEF, S_VOL_LEAK) = range(16)
N_STATES = 16
_STATE_NAMES = ('position', 'velocity', 'node_a', 'node_b', 'node_pump', 'oil_accumulator',
                'motor_speed', 'speed_integrator', 'spool', 'volume_pump', 'volume_pump_to_a',
                'volume_pump_to_b', 'volume_a_to_accumulator', 'volume_b_to_accumulator',
                'volume_relief', 'volume_piston_leakage')

# Auxiliary (algebraic) outputs.
(A_PA, A_PB, A_PP, A_PACC, A_Q_PUMP, A_Q_GEO, A_Q_RELIEF, A_TORQUE, A_TORQUE_PUMP, A_BRAKE,
 A_FRICTION, A_LOAD_CELL, A_ACCEL, A_OIL_A, A_OIL_B, A_OIL_P, A_Q_PA, A_Q_PB, A_Q_AT, A_Q_BT,
 A_STOP, A_SETPOINT) = range(22)
N_AUX = 22
_AUX_NAMES = ('pressure_a', 'pressure_b', 'pressure_pump', 'pressure_accumulator', 'pump_flow',
              'pump_flow_geometric', 'relief_flow', 'motor_torque', 'pump_torque',
              'brake_force', 'friction_force', 'load_force', 'acceleration', 'oil_a', 'oil_b',
              'oil_pump', 'flow_pump_to_a', 'flow_pump_to_b', 'flow_a_to_accumulator',
              'flow_b_to_accumulator', 'stop_force', 'motor_speed_setpoint')


@njit(cache=True)
def _node(z, volume, air0, void_compliance, bulk, gamma, p_atm, p_cav):
    """Return a node's pressure, oil content and compliance dV/dp from its state z."""
    p = z if z > p_cav else p_cav
    gas = 0.0
    if air0 > 0.0:
        gas = air0 * (p_atm / (p + p_atm)) ** (1.0 / gamma)
    liquid = max(volume - gas, 1e-9)
    if z > p_cav:
        content = liquid * math.exp(p / bulk)
        compliance = liquid / bulk + gas / (gamma * (p + p_atm))
    else:
        # Vapour of volume C_v (p_cav - z) fills what the oil does not.
        content = (liquid - void_compliance * (p_cav - z)) * math.exp(p / bulk)
        compliance = void_compliance
    return p, content, compliance


@njit(cache=True)
def _orifice(gain, opening, dp, p_laminar):
    """Return the flow through a square-root orifice, laminar below about p_laminar."""
    return gain * opening * dp / (dp * dp + p_laminar * p_laminar) ** 0.25


@njit(cache=True)
def _rhs(y, side, setpoint, prm, dy, aux):
    """Write the state derivative into dy and the algebraic outputs into aux."""
    x = y[S_X]
    v = y[S_V]
    area_a = prm[I_AREA_A]
    area_b = prm[I_AREA_B]
    bulk = prm[I_BULK]
    gamma = prm[I_GAMMA]
    p_atm = prm[I_P_ATM]
    p_cav = prm[I_P_CAV]

    vol_a = prm[I_VOL_A0] + area_a * x
    vol_b = prm[I_VOL_B0] + area_b * (prm[I_STROKE] - x)
    p_a, oil_a, comp_a = _node(y[S_ZA], vol_a, prm[I_AIR_A], prm[I_VOID_A], bulk, gamma, p_atm,
                               p_cav)
    p_b, oil_b, comp_b = _node(y[S_ZB], vol_b, prm[I_AIR_B], prm[I_VOID_B], bulk, gamma, p_atm,
                               p_cav)
    p_p, oil_p, comp_p = _node(y[S_ZP], prm[I_VOL_P], 0.0, prm[I_VOID_P], bulk, gamma, p_atm,
                               p_cav)

    stored = y[S_ACC]
    acc_volume = prm[I_ACC_VOL]
    if stored >= 0.0:
        p_acc = (prm[I_CHARGE] + p_atm) * (acc_volume / (acc_volume - stored)) ** prm[I_POLY]
        p_acc -= p_atm
    else:
        # Emptied: the gas rests on its stop and only the port's oil is left to compress.
        p_acc = max(prm[I_CHARGE] + stored * bulk / prm[I_ACC_PORT], p_cav)

    # Direction valve: four proportionally opening paths, closed at mid-travel.
    spool = y[S_SPOOL]
    open_pos = max(spool, 0.0)
    open_neg = max(-spool, 0.0)
    gain = prm[I_VALVE_K]
    p_lam = prm[I_P_LAMINAR]
    q_pa = _orifice(gain, open_pos, p_p - p_a, p_lam)
    q_pb = _orifice(gain, open_neg, p_p - p_b, p_lam)
    q_at = _orifice(gain, open_neg, p_a - p_acc, p_lam)
    q_bt = _orifice(gain, open_pos, p_b - p_acc, p_lam)

    # Pump: one-way, leaking back to its inlet (the accumulator).
    speed = max(y[S_N], 0.0)
    dp_pump = p_p - p_acc
    q_geo = prm[I_DISP] * max(speed - prm[I_DEADZONE], 0.0)
    q_pump = q_geo - prm[I_LEAK] * dp_pump - prm[I_LEAK2] * dp_pump * abs(dp_pump)
    p_set = prm[I_RELIEF_SET]
    q_relief = prm[I_RELIEF_GAIN] * max(dp_pump - p_set, 0.0)
    q_relief += prm[I_CRACK_GAIN] * max(min(dp_pump, p_set) - prm[I_CRACK_P], 0.0)
    q_leak = prm[I_CYL_LEAK] * (p_a - p_b)

    dy[S_ZA] = (math.exp(-p_a / bulk) * (q_pa - q_at - q_leak) - area_a * v) / comp_a
    dy[S_ZB] = (math.exp(-p_b / bulk) * (q_pb - q_bt + q_leak) + area_b * v) / comp_b
    dy[S_ZP] = math.exp(-p_p / bulk) * (q_pump - q_pa - q_pb - q_relief) / comp_p
    dy[S_ACC] = q_at + q_bt + q_relief - q_pump

    # Motor with its PI speed loop, current (torque) limited and one-way.
    eff = prm[I_EFF]
    torque_pump = prm[I_DISP] * dp_pump / eff if dp_pump > 0.0 else prm[I_DISP] * dp_pump * eff
    error = setpoint - speed
    torque_pi = prm[I_KP_N] * (prm[I_BETA] * setpoint - speed) + y[S_INT]
    torque_max = prm[I_TORQUE_MAX]
    torque_min = prm[I_TORQUE_MIN]
    torque = min(max(torque_pi, torque_min), torque_max)
    windup = (torque_pi > torque_max and error > 0.0) or (torque_pi < torque_min and error < 0.0)
    dy[S_INT] = 0.0 if windup else prm[I_KI_N] * error
    dn = (torque - torque_pump - prm[I_MOTOR_DAMP] * speed) / prm[I_INERTIA]
    if y[S_N] <= 0.0 and dn < 0.0:
        dn = 0.0
    dy[S_N] = dn

    dy[S_SPOOL] = (side - spool) / prm[I_TAU_V]

    # Mechanics: the brake and seal friction resist motion; end stops push back only.
    brake = prm[I_BRAKE_F] * math.tanh(v / prm[I_BRAKE_V]) + prm[I_BRAKE_C] * v
    friction = prm[I_COULOMB] * math.tanh(v / prm[I_COULOMB_V])
    stop = 0.0
    if x < 0.0:
        stop = max(-prm[I_STOP_K] * x - prm[I_STOP_C] * v, 0.0)
    elif x > prm[I_STROKE]:
        stop = min(-prm[I_STOP_K] * (x - prm[I_STROKE]) - prm[I_STOP_C] * v, 0.0)
    accel = (area_a * p_a - area_b * p_b - prm[I_DAMPING] * v - brake - friction + stop)
    accel /= prm[I_MASS]
    dy[S_X] = v
    dy[S_V] = accel

    dy[S_VOL_PUMP] = q_pump
    dy[S_VOL_PA] = q_pa
    dy[S_VOL_PB] = q_pb
    dy[S_VOL_AT] = q_at
    dy[S_VOL_BT] = q_bt
    dy[S_VOL_RELIEF] = q_relief
    dy[S_VOL_LEAK] = q_leak

    aux[A_PA] = p_a
    aux[A_PB] = p_b
    aux[A_PP] = p_p
    aux[A_PACC] = p_acc
    aux[A_Q_PUMP] = q_pump
    aux[A_Q_GEO] = q_geo
    aux[A_Q_RELIEF] = q_relief
    aux[A_TORQUE] = torque
    aux[A_TORQUE_PUMP] = torque_pump
    aux[A_BRAKE] = brake
    aux[A_FRICTION] = friction
    # The load cell sits between the rod and the load: it also carries the load's inertia.
    aux[A_LOAD_CELL] = brake + prm[I_LOAD_MASS] * accel
    aux[A_ACCEL] = accel
    aux[A_OIL_A] = oil_a
    aux[A_OIL_B] = oil_b
    aux[A_OIL_P] = oil_p
    aux[A_Q_PA] = q_pa
    aux[A_Q_PB] = q_pb
    aux[A_Q_AT] = q_at
    aux[A_Q_BT] = q_bt
    aux[A_STOP] = stop
    aux[A_SETPOINT] = setpoint


@njit(cache=True)
def _simulate(prm, y0, x_ref, v_ref, position_noise, commands_in, n_pre, substeps, dt,
              delay_substeps):
    """Run the rig: n_pre samples holding x_ref[0], then one record of len(x_ref) samples.

    With commands_in non-empty the loop is open: those signed commands replace the controller.
    Returns the recorded commands, the valve sides, the states and the algebraic outputs.
    """
    n = x_ref.size
    total = n_pre + n
    open_loop = commands_in.size > 0
    commands = np.zeros(total)
    sides = np.ones(total)
    states = np.zeros((n, N_STATES))
    auxes = np.zeros((n, N_AUX))
    y = y0.copy()
    k1 = np.zeros(N_STATES)
    k2 = np.zeros(N_STATES)
    k3 = np.zeros(N_STATES)
    k4 = np.zeros(N_STATES)
    tmp = np.zeros(N_STATES)
    aux = np.zeros(N_AUX)
    h = dt / substeps
    side = 1.0
    for kk in range(total):
        k = kk - n_pre
        if open_loop:
            u = commands_in[k] if k >= 0 else 0.0
            if u != 0.0:
                side = 1.0 if u > 0.0 else -1.0
            magnitude = abs(u)
        else:
            # The controller reads the (noisy, quantised) position and holds its output.
            if k >= 0:
                reading = y[S_X] + position_noise[k]
                target = x_ref[k]
                speed_ref = v_ref[k]
            else:
                reading = y[S_X]
                target = x_ref[0]
                speed_ref = 0.0
            reading = np.round(reading / prm[I_POS_RES]) * prm[I_POS_RES]
            k_ff = prm[I_KFF_EXT] if speed_ref > 0.0 else prm[I_KFF_RET]
            u = k_ff * speed_ref + prm[I_KP_X] * (target - reading)
            u = min(max(u, -prm[I_SPEED_MAX]), prm[I_SPEED_MAX])
            if u > prm[I_DEADBAND]:
                side = 1.0
            elif u < -prm[I_DEADBAND]:
                side = -1.0
            magnitude = abs(u)
        commands[kk] = side * magnitude
        sides[kk] = side
        for i in range(substeps):
            # The command acts delay_substeps after it was sent (none before the first).
            j = (kk * substeps + i - delay_substeps) // substeps
            side_now = sides[j] if j >= 0 else 1.0
            setpoint = abs(commands[j]) if j >= 0 else 0.0
            _rhs(y, side_now, setpoint, prm, k1, aux)
            if i == 0 and k >= 0:
                states[k, :] = y
                auxes[k, :] = aux
            for m in range(N_STATES):
                tmp[m] = y[m] + 0.5 * h * k1[m]
            _rhs(tmp, side_now, setpoint, prm, k2, aux)
            for m in range(N_STATES):
                tmp[m] = y[m] + 0.5 * h * k2[m]
            _rhs(tmp, side_now, setpoint, prm, k3, aux)
            for m in range(N_STATES):
                tmp[m] = y[m] + h * k3[m]
            _rhs(tmp, side_now, setpoint, prm, k4, aux)
            for m in range(N_STATES):
                y[m] += h / 6.0 * (k1[m] + 2.0 * k2[m] + 2.0 * k3[m] + k4[m])
            if y[S_N] < 0.0:
                y[S_N] = 0.0
    return commands[n_pre:], sides[n_pre:], states, auxes


def _plant(parameters: dict[str, float], effect: str, size: float) -> dict[str, float]:
    """Return every constant the simulation uses, from a record's nuisance values and effect."""
    ds = _DS
    area_a, area_b = _area_a(ds), _area_b(ds)
    stroke = ds['stroke']
    displacement = ds['pump_displacement']
    bulk = parameters['bulk_modulus']
    volume_a0, volume_b0 = parameters['dead_volume_a'], parameters['dead_volume_b']
    volume_p = ds['pump_outlet_volume']
    torque_max = parameters['motor_torque_peak']
    sizes = dict.fromkeys(EFFECTS, 0.0)
    if effect != 'none':
        sizes[effect] = size
    air = sizes['entrained_air']
    plant = {
        'area_a': area_a,
        'area_b': area_b,
        'stroke': stroke,
        'dead_volume_a': volume_a0,
        'dead_volume_b': volume_b0,
        'pump_outlet_volume': volume_p,
        'bulk_modulus': bulk,
        'pump_displacement': displacement,
        'pump_leakage': parameters['pump_leakage'],
        'pump_quadratic_leakage': sizes['quadratic_leakage'],
        'pump_deadzone': sizes['pump_deadzone'],
        'pump_mechanical_efficiency': ds['pump_mechanical_efficiency'],
        'motor_inertia': parameters['motor_inertia'],
        'motor_damping': parameters['motor_damping'],
        'motor_speed_gain': parameters['motor_speed_gain'],
        'motor_speed_integral_gain': parameters['motor_speed_integral_gain'],
        'motor_setpoint_weight': ds['motor_setpoint_weight'],
        'motor_torque_peak': torque_max,
        # The drive may brake the motor a little, never drive it backwards.
        'motor_torque_min': -0.1 * torque_max,
        'valve_time_constant': parameters['valve_time_constant'],
        'valve_gain': ds['valve_rated_flow'] / math.sqrt(parameters['valve_pressure_drop']),
        'valve_laminar_pressure': 0.1e6,
        'relief_gain': ds['relief_gain'],
        'relief_pressure': ds['relief_pressure'],
        # A leaking relief valve passes nothing until it cracks; the crack at the setting is
        # the healthy valve. Its gain lets 0.3 L/min through 1 MPa above the crack.
        'relief_crack_gain': 5e-12,
        'relief_crack_pressure': (sizes['relief_valve'] if effect == 'relief_valve'
                                  else ds['relief_pressure']),
        'cylinder_leakage': parameters['cylinder_leakage'],
        'cavitation_pressure': ds['cavitation_pressure'],
        'void_compliance_a': volume_a0 / bulk,
        'void_compliance_b': volume_b0 / bulk,
        'void_compliance_pump': volume_p / bulk,
        # Trapped free air: the effect's fraction of each chamber's mid-stroke volume.
        'air_volume_a': air * (volume_a0 + area_a * stroke / 2.0),
        'air_volume_b': air * (volume_b0 + area_b * stroke / 2.0),
        'air_fraction': air,
        'air_adiabatic_index': 1.4,
        'atmospheric_pressure': P_ATM,
        'charge_pressure': parameters['charge_pressure'],
        'accumulator_volume': parameters['accumulator_volume'],
        'polytropic_index': ds['polytropic_index'],
        'accumulator_port_volume': 5e-6,
        'moving_mass': parameters['moving_mass'],
        'damping': parameters['damping'],
        'brake_force': parameters['brake_force'],
        'brake_velocity': parameters['brake_velocity'],
        'brake_damping': parameters['brake_damping'],
        'coulomb_friction': sizes['coulomb_friction'],
        'coulomb_velocity': 1e-3,
        'stop_stiffness': 2e7,
        'stop_damping': 2e4,
        'load_mass': parameters['moving_mass'] - parameters['piston_mass'],
        # Position loop: 50 rad/s of motor speed per mm of error (a crossover near 6 rad/s,
        # well inside the lags of valve, motor, oil and sampling), feedforward by direction.
        'position_gain': 5e4,
        'feedforward_extend': area_a / displacement,
        'feedforward_retract': area_b / displacement,
        'motor_speed_max': ds['motor_speed_max'],
        'valve_deadband': 2.0,
        'position_resolution': POSITION_RESOLUTION,
        'transport_delay': sizes['transport_delay'],
        'accumulator_fill': ds['accumulator_fill'],
        'start_position': MID_STROKE,
    }
    return plant


def _parameter_vector(plant: dict[str, float]) -> np.ndarray:
    prm = np.zeros(N_PARAMS)
    values = {
        I_AREA_A: 'area_a', I_AREA_B: 'area_b', I_STROKE: 'stroke', I_VOL_A0: 'dead_volume_a',
        I_VOL_B0: 'dead_volume_b', I_VOL_P: 'pump_outlet_volume', I_BULK: 'bulk_modulus',
        I_DISP: 'pump_displacement', I_LEAK: 'pump_leakage', I_LEAK2: 'pump_quadratic_leakage',
        I_DEADZONE: 'pump_deadzone', I_EFF: 'pump_mechanical_efficiency',
        I_INERTIA: 'motor_inertia', I_MOTOR_DAMP: 'motor_damping', I_KP_N: 'motor_speed_gain',
        I_KI_N: 'motor_speed_integral_gain', I_BETA: 'motor_setpoint_weight',
        I_TORQUE_MAX: 'motor_torque_peak', I_TORQUE_MIN: 'motor_torque_min',
        I_TAU_V: 'valve_time_constant', I_VALVE_K: 'valve_gain',
        I_P_LAMINAR: 'valve_laminar_pressure', I_RELIEF_GAIN: 'relief_gain',
        I_RELIEF_SET: 'relief_pressure', I_CRACK_GAIN: 'relief_crack_gain',
        I_CRACK_P: 'relief_crack_pressure', I_CYL_LEAK: 'cylinder_leakage',
        I_P_CAV: 'cavitation_pressure', I_VOID_A: 'void_compliance_a',
        I_VOID_B: 'void_compliance_b', I_VOID_P: 'void_compliance_pump',
        I_AIR_A: 'air_volume_a', I_AIR_B: 'air_volume_b', I_GAMMA: 'air_adiabatic_index',
        I_P_ATM: 'atmospheric_pressure', I_CHARGE: 'charge_pressure',
        I_ACC_VOL: 'accumulator_volume', I_POLY: 'polytropic_index',
        I_ACC_PORT: 'accumulator_port_volume', I_MASS: 'moving_mass', I_DAMPING: 'damping',
        I_BRAKE_F: 'brake_force', I_BRAKE_V: 'brake_velocity', I_BRAKE_C: 'brake_damping',
        I_COULOMB: 'coulomb_friction', I_COULOMB_V: 'coulomb_velocity',
        I_STOP_K: 'stop_stiffness', I_STOP_C: 'stop_damping', I_LOAD_MASS: 'load_mass',
        I_KP_X: 'position_gain', I_KFF_EXT: 'feedforward_extend',
        I_KFF_RET: 'feedforward_retract', I_SPEED_MAX: 'motor_speed_max',
        I_DEADBAND: 'valve_deadband', I_POS_RES: 'position_resolution',
    }
    for index, name in values.items():
        prm[index] = plant[name]
    return prm


def _initial_state(plant: dict[str, float]) -> np.ndarray:
    """Return the state at rest at the start position, every node at the accumulator's pressure."""
    y = np.zeros(N_STATES)
    y[S_X] = plant['start_position']
    stored = plant['accumulator_fill'] * plant['accumulator_volume']
    p_acc = _accumulator_pressure(stored, plant['accumulator_volume'], plant['charge_pressure'],
                                  plant['polytropic_index'])
    y[S_ACC] = stored
    y[S_ZA] = y[S_ZB] = y[S_ZP] = p_acc
    y[S_SPOOL] = 1.0  # the de-energised 4/2 valve: pump to A
    return y


def run(plant: dict[str, float], x_ref: np.ndarray, v_ref: np.ndarray,
        position_noise: np.ndarray | None = None, commands: np.ndarray | None = None,
        rate: float = RATE, substeps: int | None = None) -> dict[str, np.ndarray]:
    """Simulate the rig and return its noise-free signals at the sample times.

    Parameters
    ----------
    plant : dict of str to float
        Every constant (``Draw.plant``).
    x_ref, v_ref : numpy.ndarray
        Position [m] and velocity [m/s] references, one per sample.
    position_noise : numpy.ndarray, optional
        Noise the controller's position reading carries [m]; none by default.
    commands : numpy.ndarray, optional
        Signed motor speed commands [rad/s] that replace the controller (open loop).
    rate : float
        Sample rate [Hz].
    substeps : int, optional
        RK4 steps per sample; ``SUBSTEPS`` by default.

    Returns
    -------
    dict of str to numpy.ndarray
        The states, algebraic outputs, ``command`` (signed, as sent) and ``side``.
    """
    substeps = SUBSTEPS if substeps is None else substeps
    n = x_ref.size
    noise = np.zeros(n) if position_noise is None else np.asarray(position_noise, float)
    cmd_in = np.zeros(0) if commands is None else np.asarray(commands, float)
    dt = 1.0 / rate
    delay = round(plant['transport_delay'] / (dt / substeps))
    n_pre = round(PRE_ROLL * rate)
    cmd, side, states, auxes = _simulate(
        _parameter_vector(plant), _initial_state(plant), np.asarray(x_ref, float),
        np.asarray(v_ref, float), noise, cmd_in, n_pre, substeps, dt, delay)
    out = {name: states[:, i].copy() for i, name in enumerate(_STATE_NAMES)}
    out.update({name: auxes[:, i].copy() for i, name in enumerate(_AUX_NAMES)})
    out['command'] = cmd
    out['side'] = side
    return out


def _sine_sum(rng: np.random.Generator, time: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                    dict[str, float]]:
    """Return a ramped-in sum of sines around mid stroke, its velocity and its parameters."""
    count = int(rng.integers(5, 9))
    # One slow sine carries the stroke; the others, log-uniform up to 2 Hz, reverse the rod.
    freqs = np.sort(np.concatenate([[rng.uniform(0.1, 0.15)],
                                    np.exp(rng.uniform(math.log(0.2), math.log(2.0), count - 1))]))
    phases = rng.uniform(0.0, 2.0 * math.pi, count)
    # Amplitudes fall as f^-1.5: the velocity amplitudes then fall only as f^-0.5.
    weights = freqs ** -1.5 * rng.uniform(0.5, 1.5, count)
    amplitude = rng.uniform(0.035, 0.045)  # peak excursion [m]
    # Peak speed [m/s]: extending at the motor's top speed is 0.039 m/s. This cap, not the
    # excursion, usually sets the scale: sines over 0.1-2 Hz at these speeds span +-15-35 mm.
    speed_cap = rng.uniform(0.028, 0.036)
    ramp_time = 2.0
    fine = np.arange(0.0, max(time[-1], 1.0) + 1e-3, 1e-3)
    arg = 2.0 * math.pi * np.outer(fine, freqs) + phases
    shape = np.sin(arg) @ weights
    slope = np.cos(arg) @ (2.0 * math.pi * freqs * weights)
    scale = min(amplitude / np.max(np.abs(shape)), speed_cap / np.max(np.abs(slope)))
    weights = weights * scale
    arg = 2.0 * math.pi * np.outer(time, freqs) + phases
    ramp = np.where(time < ramp_time, 0.5 * (1.0 - np.cos(math.pi * time / ramp_time)), 1.0)
    d_ramp = np.where(time < ramp_time,
                      0.5 * math.pi / ramp_time * np.sin(math.pi * time / ramp_time), 0.0)
    wave = np.sin(arg) @ weights
    d_wave = np.cos(arg) @ (2.0 * math.pi * freqs * weights)
    x_ref = MID_STROKE + ramp * wave
    v_ref = ramp * d_wave + d_ramp * wave
    params = {'count': float(count), 'ramp_time': ramp_time, 'center': MID_STROKE,
              'amplitude_target': amplitude, 'speed_cap': speed_cap}
    for i in range(count):
        params[f'frequency_{i}'] = float(freqs[i])
        params[f'amplitude_{i}'] = float(weights[i])
        params[f'phase_{i}'] = float(phases[i])
    return x_ref, v_ref, params


def _steps(rng: np.random.Generator, time: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                dict[str, float]]:
    """Return trapezoidal-speed moves between random positions with dwells, and parameters."""
    half_range = 0.05
    accel = rng.uniform(0.2, 1.0)  # [m/s^2]
    speed_max = rng.uniform(0.02, 0.035)  # [m/s]
    starts, origins, distances, speeds = [], [], [], []
    t, position = 0.0, MID_STROKE
    while t < time[-1]:
        t += rng.uniform(0.3, 1.2)  # dwell
        target = position
        while abs(target - position) < 0.01:
            target = MID_STROKE + rng.uniform(-half_range, half_range)
        speed = speed_max * rng.uniform(0.6, 1.0)
        distance = target - position
        # Triangular when too short to reach the speed.
        speed = min(speed, math.sqrt(abs(distance) * accel))
        starts.append(t)
        origins.append(position)
        distances.append(distance)
        speeds.append(speed)
        t += abs(distance) / speed + speed / accel
        position = target
    x_ref = np.full(time.size, MID_STROKE)
    v_ref = np.zeros(time.size)
    for start, origin, distance, speed in zip(starts, origins, distances, speeds, strict=True):
        ramp = speed / accel
        duration = abs(distance) / speed + ramp
        tau = time - start
        sign = math.copysign(1.0, distance)
        rising = tau < ramp
        falling = tau > duration - ramp
        # Speed profile: up at accel, cruise, down at accel; integrate piecewise.
        vel = np.where(rising, accel * tau, np.where(falling, accel * (duration - tau), speed))
        pos = np.where(
            rising, 0.5 * accel * tau ** 2,
            np.where(falling, abs(distance) - 0.5 * accel * (duration - tau) ** 2,
                     0.5 * accel * ramp ** 2 + speed * (tau - ramp)))
        inside = (tau >= 0.0) & (tau <= duration)
        x_ref = np.where(inside, origin + sign * pos, np.where(tau > duration,
                                                                 origin + distance, x_ref))
        v_ref = np.where(inside, sign * vel, v_ref)
    params = {'acceleration': accel, 'speed_max': speed_max, 'moves': float(len(starts)),
              'half_range': half_range, 'center': MID_STROKE}
    return x_ref, v_ref, params


@dataclass(frozen=True)
class Draw:
    """One record of the rig: what was drawn, what was measured and the noise-free truth.

    Attributes
    ----------
    seed : int
        The record's seed.
    effect : str
        One of ``EFFECT_CHOICES``.
    size : float
        The effect's size, SI; 0 for 'none'.
    joint_type : str
        Always 'hip'.
    excitation : str
        One of ``EXCITATIONS``.
    parameters : dict of str to float
        The drawn nuisance values.
    noise : dict of str to float
        Sensor noise standard deviations and resolutions.
    period : float
        Sample period [s].
    columns : dict of str to numpy.ndarray
        Measured data, keys ``COLUMNS``.
    clean : dict of str to numpy.ndarray
        Noise-free signals (states, pressures, flows, forces, torques, oil contents).
    plant : dict of str to float
        Every constant used.
    excitation_parameters : dict of str to float
        The excitation's drawn values.
    """

    seed: int
    effect: str
    size: float
    joint_type: str
    excitation: str
    parameters: dict[str, float]
    noise: dict[str, float]
    period: float
    columns: dict[str, np.ndarray] = field(repr=False)
    clean: dict[str, np.ndarray] = field(repr=False)
    plant: dict[str, float] = field(repr=False)
    excitation_parameters: dict[str, float] = field(repr=False)

    @property
    def effects(self) -> dict[str, float]:
        """Return {} for 'none', else {effect: size}."""
        return {} if self.effect == 'none' else {self.effect: self.size}


def draw(seed: int, *, effect: str | None = None, size: float | None = None,
         excitation: str | None = None, duration: float = 20.0, rate: float = RATE,
         brake_force: float | None = None, excursion: float = 1.0,
         charge_pressure: float | None = None) -> Draw:
    """Draw and simulate one record.

    Every variate comes from ``numpy.random.default_rng(seed)`` in a fixed order whatever is
    forced, so forcing one choice leaves the others unchanged: the same seed with another
    effect is the same rig, excitation and noise (a twin).

    Parameters
    ----------
    seed : int
        Seed of the record.
    effect : str, optional
        Force the hidden effect (one of ``EFFECT_CHOICES``).
    size : float, optional
        Force its size, SI; by default drawn in ``effect_range(effect, parameters)``.
    excitation : str, optional
        Force the excitation (one of ``EXCITATIONS``).
    duration : float
        Record length [s].
    rate : float
        Sample rate [Hz].
    brake_force : float, optional
        Force the brake's force [N].
    excursion : float
        Scale of the excitation about mid stroke (its positions and speeds): 0.1 moves the
        rod over a tenth of the stroke it would, as a rig that creeps against its brake.
    charge_pressure : float, optional
        Force the accumulator's charge pressure [Pa].

    Returns
    -------
    Draw
        The record.
    """
    rng = np.random.default_rng(seed)
    drawn_effect = EFFECT_CHOICES[int(rng.integers(len(EFFECT_CHOICES)))]
    size_fraction = float(rng.random())
    drawn_excitation = EXCITATIONS[int(rng.integers(len(EXCITATIONS)))]
    parameters = {name: float(rng.uniform(low, high)) for name, low, high in _NUISANCE}
    drawn_brake = float(rng.uniform(*BRAKE_FORCE_RANGE))
    noise = {name: float(rng.uniform(low, high)) for name, low, high in _NOISE}
    sine_rng, steps_rng, noise_rng = rng.spawn(3)

    effect = drawn_effect if effect is None else effect
    excitation = drawn_excitation if excitation is None else excitation
    if effect not in EFFECT_CHOICES:
        raise ValueError(f'unknown effect {effect!r}; choose from {EFFECT_CHOICES}')
    if excitation not in EXCITATIONS:
        raise ValueError(f'unknown excitation {excitation!r}; choose from {EXCITATIONS}')
    parameters['brake_force'] = drawn_brake if brake_force is None else float(brake_force)
    if charge_pressure is not None:
        parameters['charge_pressure'] = float(charge_pressure)
    if not excursion > 0.0:
        raise ValueError(f'excursion must be positive, got {excursion!r}')
    if effect == 'none':
        size = 0.0
    elif size is None:
        low, high = effect_range(effect, parameters)
        size = low + size_fraction * (high - low)
    noise['position_resolution'] = POSITION_RESOLUTION
    noise['pressure_resolution'] = _DS['pressure_sensor_range'] / (2 ** PRESSURE_BITS - 1)

    period = 1.0 / rate
    n = round(duration * rate)
    time = np.arange(n) * period
    maker = _sine_sum if excitation == 'sine_sum' else _steps
    x_ref, v_ref, excitation_parameters = maker(
        sine_rng if excitation == 'sine_sum' else steps_rng, time)
    x_ref = MID_STROKE + excursion * (x_ref - MID_STROKE)
    v_ref = excursion * v_ref
    unit = noise_rng.standard_normal((5, n))

    plant = _plant(parameters, effect, float(size))
    clean = run(plant, x_ref, v_ref, position_noise=noise['position'] * unit[0], rate=rate)
    clean['reference'] = x_ref
    clean['reference_velocity'] = v_ref

    def quantise(signal: np.ndarray, step: float) -> np.ndarray:
        return np.round(signal / step) * step

    full_scale = _DS['pressure_sensor_range']
    p_step = noise['pressure_resolution']
    columns = {
        'time': time,
        'motor_speed_command': clean['command'],
        'position': quantise(clean['position'] + noise['position'] * unit[0],
                             POSITION_RESOLUTION),
        'reference': x_ref,
        'pressure_a': np.clip(quantise(clean['pressure_a'] + noise['pressure'] * unit[1],
                                       p_step), 0.0, full_scale),
        'pressure_b': np.clip(quantise(clean['pressure_b'] + noise['pressure'] * unit[2],
                                       p_step), 0.0, full_scale),
        'motor_speed': clean['side'] * clean['motor_speed'] + noise['motor_speed'] * unit[3],
        'load_force': clean['load_force'] + noise['load_force'] * unit[4],
    }
    return Draw(seed=seed, effect=effect, size=float(size), joint_type='hip',
                excitation=excitation, parameters=parameters, noise=noise, period=period,
                columns=columns, clean=clean, plant=plant,
                excitation_parameters=excitation_parameters)


def write_csv(draw: Draw, path: str | Path, columns: tuple[str, ...] = COLUMNS) -> None:
    """Write a record's measured columns to a CSV file.

    Parameters
    ----------
    draw : Draw
        The record.
    path : str or pathlib.Path
        Where to write.
    columns : tuple of str
        Which columns; 'time' is always written, first.
    """
    names = ['time', *(name for name in columns if name != 'time')]
    unknown = [name for name in names if name not in draw.columns]
    if unknown:
        raise ValueError(f'unknown columns {unknown}; choose from {COLUMNS}')
    data = np.column_stack([draw.columns[name] for name in names])
    with Path(path).open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in data:
            writer.writerow([f'{value:.17g}' for value in row])
