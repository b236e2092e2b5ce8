"""Independent truth plant of one HAS joint and a seeded generator of measured data.

This module exists for the acceptance test of ``exo-has diagnose``: that test must not check
the project's model against itself, so the plant here is written from the paper (Sun et al.
2021, sections 2-3, Eqs. 2-10) without importing or copying ``exo_has_sim.model`` or
``exo_has_sim.simulate``. Only data are taken from the project: the nominal parameter sets
(the bench's files, ``test/rigs.py``) and, for the walking reference, Winter's gait table
through the joint linkage (``exo_has_sim.gait``, ``exo_has_sim.kinematics``).

Plant
-----
State ``[x, v, p, n, s, void]``: cylinder extension from the retracted end x [m], its velocity
v [m/s], rodless-chamber gauge pressure p [Pa] (the rod chamber is at the tank, p_B = 0), motor
speed n [rad/s], compact-valve spool s [-] (1 assist, 0 free) and the vapour volume of a
cavitation pocket [m^3]. The rodless chamber's motion flow is ``A_A v`` (Eq. 4, the rod side
open to the tank; the paper's Eq. 10 averages ``(A_A + A_B) / 2`` instead)::

    (V_0 + A_A x) / E_eff(p) dp/dt = s D_p n_pump - s (L_n p + L_n2 p|p|) - L_c p - A_A v
                                     - Q_relief - (1 - s) G_free p
    (M_a + M_L) dv/dt = A_A p - B v - F_friction - F_load + F_stop
    dn/dt = (n_drive - n) / tau_motor,        ds/dt = (s_target(n, s p) - s) / tau_valve

The compact valve's spools are pushed by the pressure at its inlet (paper 2.3.3: in assist
"when the system pressure is established", free "when the ESM stops, there is no pressure in
circuit"): ``s_target = max(S((|n| - n_release) / (n_engage - n_release)), S((s p - p_drop) /
(p_hold - p_drop)))`` with ``S(z) = 3 z^2 - 2 z^3`` on z clipped to [0, 1] and the parameter
files' ``valve_release_speed``, ``valve_engage_speed``, ``valve_drop_pressure`` and
``valve_hold_pressure``. The first term is the pressure the turning pump builds while the
valve is free; the second the chamber pressure, which the inlet sees through the opening s.
Cavitation: the pressure cannot fall below ``cavitation_pressure``; a net outflow there opens a
vapour pocket whose volume a later inflow must refill before the pressure rises again (volume
is conserved across the floor). End stops are a stiff one-sided spring-damper. The relief valve
passes ``relief_conductance (p - relief_pressure)`` above its setting.

Integration is classical RK4 on a fixed grid of ``SUBSTEPS`` steps per 5 ms sample (250 us,
0.08 rad of the fastest hydraulic mode), compiled with numba. The stiff passages (relief valve
above its setting and free mode discharge the dead volume in about 40 us) only open in short
events: a step whose length times a bound on the fastest rate of the dynamics
(:func:`_stiffness`) exceeds ``STIFF_LIMIT`` is cut into equal shorter steps, so the grid is
fixed where the dynamics are slow and the events are resolved. A step also ends where a vapour
pocket is predicted to open or close, and the cavitation floor is imposed after each step by
moving any overshoot into the pocket. Commands and load forces are held for one sample
(zero-order hold); a transport delay switches the drive within a sample, where the sample is
split, so the delay is exact.

Valve events. A loaded valve stays in assist while the motor passes through zero: the chamber
pressure (above 1 MPa near every reversal of 40 effect-free draws of each excitation) holds
the spool at its seat. It falls to free mode only once the motor has stopped and the chamber
pressure is below ``valve_drop_pressure`` (0.2 MPa), as for an unloaded joint at rest, and
the turning motor brings it back. With the earlier law, by motor speed alone, the spool left
its seat at every motor reversal, the free passage (1e-10 m^3/(s Pa)) emptied the loaded
chamber within a millisecond and the re-engaging valve spiked the pressure to the relief
setting, 1-5 times a second in every draw; the closed loop was then so sensitive to those
events that its draws did not converge under step halving. Now they do, the effect-free ones
to within 1e-6 of the smallest noise.

Effects (sizes in SI, as the diagnosis reports them)
----------------------------------------------------
- ``coulomb_friction`` F_c [N]: ``F_friction = F_c tanh(v / 1 mm/s)``.
- ``pump_deadzone`` n_dz [rad/s]: ``n_pump = n - n_dz sign(n)`` for ``|n| > n_dz``, else 0.
- ``transport_delay`` tau [s]: the drive acts on the command tau after it was sent.
- ``quadratic_leakage`` L_n2 [m^3/(s Pa^2)]: pump leakage ``L_n2 p|p|``, only while engaged.
- ``relief_valve`` p_crack [Pa]: the safety valve passes
  ``RELIEF_CRACK_CONDUCTANCE (min(p, p_relief) - p_crack)`` above p_crack.
- ``entrained_air`` alpha_0 [-]: free-air volume fraction at atmospheric pressure. The air is
  compressed polytropically (exponent 1.4, adiabatic: the 20 Hz hydraulic mode is too fast
  for the heat exchange with the oil), the oil with ``bulk_modulus`` E; the mixture's modulus
  is ``E_eff = -V dp/dV = (V_oil + V_air) / (V_oil / E + V_air / (1.4 p_abs))`` with
  ``V_air / V_oil = alpha_0 / (1 - alpha_0) (p_atm / p_abs)^(1 / 1.4) exp(p / E)``.

Data
----
:func:`draw` draws, from ``numpy.random.default_rng(seed)``, the effect and its size, the
hard-to-know parameters, the excitation, the load and the sensor noise, and runs the plant in
closed loop under its own PD position controller at 200 Hz. See :data:`EFFECT_RANGES`,
:data:`NOISE_RANGES` and :func:`draw` for the distributions and the reasons for them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from rigs import motion_scale, rig_parameters

from exo_has_sim.gait import GaitCycle, load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters

FloatArray = NDArray[np.float64]

JOINT_TYPES = ('hip', 'knee')
EFFECTS = ('coulomb_friction', 'pump_deadzone', 'transport_delay', 'quadratic_leakage',
           'relief_valve', 'entrained_air')
EFFECT_CHOICES = ('none', *EFFECTS)
EXCITATIONS = ('sine_sum', 'walk', 'squat')
COLUMNS = ('time', 'motor_speed_command', 'position', 'reference', 'pressure_a', 'pressure_b',
           'motor_speed', 'load_force')

#: Sample rate of the controller and of the recorded data [Hz] (paper 4.2: 200 Hz).
SAMPLE_RATE = 200.0
#: RK4 steps per sample outside stiff events: 250 us, 0.08 rad of the fastest hydraulic mode.
SUBSTEPS = 20
#: Largest product of RK4 step and fastest rate of the dynamics (:func:`_stiffness`).
STIFF_LIMIT = 0.1
#: PD gains of the truth plant's controller: kp [(rad/s)/m], kd [(rad/s)/(m/s)] (paper 5.1,
#: P = 35 per mm and D = 15, as the project reads them); kff = A_A / D_p is added per plant.
KP = 35.0e3
KD = 15.0

#: Width of the tanh that smooths the sign of the Coulomb friction [m/s].
FRICTION_SMOOTHING_VELOCITY = 1.0e-3
#: Conductance of the cracked safety valve between its crack pressure and its setting
#: [m^3/(s Pa)]: 0.12 L/min per MPa, so the full pump flow (1.6 L/min) would need 13 MPa above
#: cracking. Softer than a healthy relief characteristic (full flow within about 10 % of the
#: setting), as a weeping, partly open valve is; at the highest loads drawn it takes up to
#: about half the pump's flow, so the loop still tracks and the effect shows as extra motor
#: speed at high pressure rather than a collapse of the load.
RELIEF_CRACK_CONDUCTANCE = 2.0e-12
#: Polytropic exponent of the entrained air (adiabatic).
AIR_POLYTROPIC_EXPONENT = 1.4
ATMOSPHERIC_PRESSURE = 101_325.0  # Pa

#: Size range of each effect: (low, high, 'log' or 'linear' spacing of the uniform draw).
#: Each low end changes the noise-free response by clearly more than the largest noise drawn
#: (checked in test_truth_plant.py); each high end is still a plausible fault of a small EHA.
EFFECT_RANGES: dict[str, tuple[float, float, str]] = {
    # 25-150 N: 1.4-8.5 % of the hip's 1770 N peak thrust, 0.16-1 MPa of chamber pressure.
    'coulomb_friction': (25.0, 150.0, 'log'),
    # 5-40 rad/s: 1.2-10 % of the 4000 r/min top speed (50-380 r/min).
    'pump_deadzone': (5.0, 40.0, 'log'),
    # 2-20 ms: from well under one 5 ms sample (a fast drive) to four samples (a slow bus).
    'transport_delay': (2.0e-3, 20.0e-3, 'log'),
    # At 12 MPa it leaks 0.4-2.5 times the nominal linear leakage (1.8 cm^3/s).
    'quadratic_leakage': (5.0e-21, 3.0e-20, 'log'),
    # 44-61 % of the 18 MPa setting: below the 11.5-14 MPa peak load pressures of every draw.
    'relief_valve': (8.0e6, 11.0e6, 'linear'),
    # 6-20 % free air at atmospheric pressure: a poorly bled small circuit (a trapped bubble of
    # 1.1-3.6 cm^3 in the 18 cm^3 rodless chamber at mid stroke). The load keeps the chamber at
    # 1-14 MPa, where the air takes a 5-35 times smaller volume: the 1 % of a well bled circuit
    # changes the response by less than the noise. (5 % was the low end while the plant's flow
    # balance took the averaged area of the paper's Eq. 10; with A_A, a sine sum's closed loop
    # kept 5 % to 0.92 of the largest noise.)
    'entrained_air': (0.06, 0.2, 'log'),
}

#: Sensor noise, Gaussian and white (not quantised), std drawn uniformly in these ranges [SI]:
#: the displacement sensor (position [m]), 0-25 MPa transducers at 0.04-0.2 % of full scale
#: (pressure, the same std on both chambers [Pa]), the drive's encoder speed at 200 Hz
#: (motor_speed [rad/s]) and the load cell (load_force [N]). The command is exact.
NOISE_RANGES: dict[str, tuple[float, float]] = {
    'position': (5.0e-6, 20.0e-6),
    'pressure': (10.0e3, 50.0e3),
    'motor_speed': (0.5, 2.0),
    'load_force': (1.0, 5.0),
}

#: Relative spread of the hard-to-know parameters around their nominal values (paper 4.2).
PARAMETER_SPREAD = 0.3
DRAWN_PARAMETERS = ('bulk_modulus', 'pump_leakage', 'damping')

#: Static load pressure ranges [Pa] (load force / A_A): lowest in the cycle, then highest.
LOAD_PRESSURE_LOW = (1.5e6, 3.0e6)
LOAD_PRESSURE_HIGH = (11.5e6, 14.0e6)

STRIDE_FREQUENCY = 0.85  # Hz, paper 5.2
SQUAT_FREQUENCY = 0.5  # Hz, paper 5.2
RAMP_DURATION = 1.0  # s, smooth start of every reference

# Packed parameter vector of the compiled functions.
(P_DP, P_NMAX, P_TAU_M, P_LN, P_LC, P_E, P_AA, P_AE, P_STROKE, P_V0, P_M, P_B, P_PREL,
 P_GREL, P_GFREE, P_NENG, P_NREL, P_TAU_S, P_PCAV, P_KSTOP, P_CSTOP, P_FC, P_NDZ, P_LN2,
 P_PCRACK, P_GCRACK, P_AIR, P_PHOLD, P_PDROP) = range(29)
N_PACKED = 29
# State layout.
SX, SV, SP, SN, SS, SVOID = range(6)
N_STATE = 6


def _pack(params: HasParameters, effects: Mapping[str, float]) -> FloatArray:
    """Return the parameter vector of the compiled functions."""
    prm = np.zeros(N_PACKED)
    prm[P_DP] = params.pump_displacement
    prm[P_NMAX] = params.motor_speed_max
    prm[P_TAU_M] = params.motor_time_constant
    prm[P_LN] = params.pump_leakage
    prm[P_LC] = params.cylinder_leakage
    prm[P_E] = params.bulk_modulus
    prm[P_AA] = params.area_a
    prm[P_AE] = params.flow_area
    prm[P_STROKE] = params.stroke
    prm[P_V0] = params.dead_volume
    prm[P_M] = params.moving_mass
    prm[P_B] = params.damping
    prm[P_PREL] = params.relief_pressure
    prm[P_GREL] = params.relief_conductance
    prm[P_GFREE] = params.free_conductance
    prm[P_NENG] = params.valve_engage_speed
    prm[P_NREL] = params.valve_release_speed
    prm[P_TAU_S] = params.valve_time_constant
    prm[P_PHOLD] = params.valve_hold_pressure
    prm[P_PDROP] = params.valve_drop_pressure
    prm[P_PCAV] = params.cavitation_pressure
    prm[P_KSTOP] = params.end_stop_stiffness
    prm[P_CSTOP] = params.end_stop_damping
    prm[P_FC] = effects.get('coulomb_friction', 0.0)
    prm[P_NDZ] = effects.get('pump_deadzone', 0.0)
    prm[P_LN2] = effects.get('quadratic_leakage', 0.0)
    prm[P_PCRACK] = effects.get('relief_valve', 0.0)
    prm[P_GCRACK] = RELIEF_CRACK_CONDUCTANCE if prm[P_PCRACK] > 0.0 else 0.0
    prm[P_AIR] = effects.get('entrained_air', 0.0)
    return prm


@njit(cache=True)
def mixture_bulk_modulus(p: float, oil_modulus: float, air_fraction: float) -> float:
    """Bulk modulus [Pa] of oil with a free-air fraction at atmospheric pressure, at gauge p.

    Parameters
    ----------
    p : float
        Gauge pressure [Pa].
    oil_modulus : float
        Bulk modulus of the oil (and hose) without air [Pa].
    air_fraction : float
        Free-air volume fraction at atmospheric pressure [-].

    """
    if air_fraction <= 0.0:
        return oil_modulus
    p_abs = max(p + ATMOSPHERIC_PRESSURE, 1.0e3)  # the floor only guards a solver excursion
    kappa = AIR_POLYTROPIC_EXPONENT
    # Air volume per oil volume: the air expands or shrinks polytropically from atmospheric
    # pressure, the oil with its own modulus.
    air = (air_fraction / (1.0 - air_fraction) * (ATMOSPHERIC_PRESSURE / p_abs) ** (1.0 / kappa)
           * math.exp(p / oil_modulus))
    return (1.0 + air) / (1.0 / oil_modulus + air / (kappa * p_abs))


@njit(cache=True)
def _smoothstep(z: float) -> float:
    """Return ``3 z^2 - 2 z^3`` on z clipped to [0, 1]."""
    z = min(max(z, 0.0), 1.0)
    return z * z * (3.0 - 2.0 * z)


@njit(cache=True)
def _spool_target(n: float, p: float, s: float, prm: FloatArray) -> float:
    """Spool position [-] the compact valve moves to; see :func:`spool_target`."""
    by_speed = _smoothstep((abs(n) - prm[P_NREL]) / (prm[P_NENG] - prm[P_NREL]))
    by_pressure = _smoothstep((s * p - prm[P_PDROP]) / (prm[P_PHOLD] - prm[P_PDROP]))
    return max(by_speed, by_pressure)


@njit(cache=True)
def _net_flow(y: FloatArray, prm: FloatArray) -> float:
    """Net flow into the rodless chamber [m^3/s]."""
    p, n, s = y[SP], y[SN], y[SS]
    dz = prm[P_NDZ]
    n_pump = n
    if dz > 0.0:
        n_pump = max(abs(n) - dz, 0.0) * (1.0 if n >= 0.0 else -1.0)
    q_relief = prm[P_GREL] * max(p - prm[P_PREL], 0.0)
    if prm[P_PCRACK] > 0.0:
        q_relief += prm[P_GCRACK] * max(min(p, prm[P_PREL]) - prm[P_PCRACK], 0.0)
    return (s * prm[P_DP] * n_pump - s * (prm[P_LN] * p + prm[P_LN2] * p * abs(p))
            - prm[P_LC] * p - prm[P_AE] * y[SV] - q_relief - (1.0 - s) * prm[P_GFREE] * p)


@njit(cache=True)
def _rhs(y: FloatArray, n_drive: float, f_load: float, prm: FloatArray,
         dy: FloatArray) -> None:
    """Write dy/dt into ``dy`` for a drive command n_drive [rad/s] and load f_load [N]."""
    x, v, p, n = y[SX], y[SV], y[SP], y[SN]
    stroke = prm[P_STROKE]
    volume = prm[P_V0] + prm[P_AA] * min(max(x, 0.0), stroke)
    capacitance = volume / mixture_bulk_modulus(p, prm[P_E], prm[P_AIR])
    q_net = _net_flow(y, prm)
    if y[SVOID] > 0.0:
        # A vapour pocket: the pressure sits on the floor until the inflow has refilled it.
        dy[SP] = 0.0
        dy[SVOID] = -q_net
    else:
        dy[SP] = q_net / capacitance
        dy[SVOID] = 0.0
    f_stop = 0.0
    if x < 0.0:
        f_stop = max(-prm[P_KSTOP] * x - prm[P_CSTOP] * v, 0.0)
    elif x > stroke:
        f_stop = min(-prm[P_KSTOP] * (x - stroke) - prm[P_CSTOP] * v, 0.0)
    f_friction = prm[P_FC] * math.tanh(v / FRICTION_SMOOTHING_VELOCITY)
    dy[SX] = v
    dy[SV] = (prm[P_AA] * p - prm[P_B] * v - f_friction - f_load + f_stop) / prm[P_M]
    drive = min(max(n_drive, -prm[P_NMAX]), prm[P_NMAX])
    dy[SN] = (drive - n) / prm[P_TAU_M]
    dy[SS] = (_spool_target(n, p, y[SS], prm) - y[SS]) / prm[P_TAU_S]


@njit(cache=True)
def _stiffness(y: FloatArray, dy: FloatArray, h: float, prm: FloatArray) -> float:
    """Bound on the fastest rate of the dynamics over the next step h [1/s].

    A passage that may open within the step counts as open: the relief and crack valves within
    a margin of their pressures (at least the pressure change the step may make), the free
    passage by as much as the spool can move once both the motor speed and the inlet pressure
    may enter their switching bands, an end stop within reach, the friction's tanh while the
    velocity is within a few smoothing widths of zero. While the inlet pressure may be in its
    band, the loop it closes (spool on pressure, pressure on spool) counts with a bound on its
    eigenvalues, ``|d| + sqrt(|b c|)`` for the Jacobian block ``[[a, b], [c, d]]`` of (p, s).
    """
    x, v, p, n, s = y[SX], y[SV], y[SP], y[SN], y[SS]
    stroke = prm[P_STROKE]
    volume = prm[P_V0] + prm[P_AA] * min(max(x, 0.0), stroke)
    capacitance = volume / mixture_bulk_modulus(p, prm[P_E], prm[P_AIR])
    margin = max(5.0e5, 2.0 * abs(dy[SP]) * h)
    conductance = s * (prm[P_LN] + 2.0 * prm[P_LN2] * abs(p)) + prm[P_LC]
    inlet = s * p
    inlet_margin = margin + 2.0 * abs(p * dy[SS]) * h
    free = 1.0 - s
    if (abs(n) < prm[P_NENG] + 2.0 * abs(dy[SN]) * h
            and inlet < prm[P_PHOLD] + inlet_margin):
        free += h / prm[P_TAU_S]  # the spool may leave its seat within the step
    conductance += min(free, 1.0) * prm[P_GFREE]
    coupling = 0.0
    if prm[P_PDROP] - inlet_margin < inlet < prm[P_PHOLD] + inlet_margin:
        # Slope of the pressure's smoothstep (at most 1.5 / span) against the spool's and the
        # chamber's sensitivity to each other.
        slope = 1.5 / (prm[P_PHOLD] - prm[P_PDROP])
        pressure_by_spool = (abs(prm[P_DP] * n) + (prm[P_LN] + prm[P_LN2] * abs(p)
                                                    + prm[P_GFREE]) * abs(p)) / capacitance
        coupling = (slope * abs(p) / prm[P_TAU_S]
                    + math.sqrt(pressure_by_spool * slope * abs(s) / prm[P_TAU_S]))
    if p > prm[P_PREL] - margin:
        conductance += prm[P_GREL]
    if prm[P_PCRACK] > 0.0 and p > prm[P_PCRACK] - margin:
        conductance += prm[P_GCRACK]
    rate = conductance / capacitance
    rate += math.sqrt(prm[P_AA] * prm[P_AE] / (capacitance * prm[P_M]))
    reach = 2.0 * abs(v) * h + 1.0e-4
    if x < reach or x > stroke - reach:
        rate += math.sqrt(prm[P_KSTOP] / prm[P_M]) + prm[P_CSTOP] / prm[P_M]
    if prm[P_FC] > 0.0 and abs(v) < 5.0 * FRICTION_SMOOTHING_VELOCITY + 2.0 * abs(dy[SV]) * h:
        rate += prm[P_FC] / (FRICTION_SMOOTHING_VELOCITY * prm[P_M])
    return rate + coupling + 1.0 / prm[P_TAU_M] + 1.0 / prm[P_TAU_S]


@njit(cache=True)
def _rk4_step(y: FloatArray, h: float, n_drive: float, f_load: float, prm: FloatArray,
              k1: FloatArray, k2: FloatArray, k3: FloatArray, k4: FloatArray,
              tmp: FloatArray) -> None:
    """Advance y in place by one RK4 step h [s] (k1 holds dy/dt at y), then cavitation."""
    for i in range(N_STATE):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    _rhs(tmp, n_drive, f_load, prm, k2)
    for i in range(N_STATE):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    _rhs(tmp, n_drive, f_load, prm, k3)
    for i in range(N_STATE):
        tmp[i] = y[i] + h * k3[i]
    _rhs(tmp, n_drive, f_load, prm, k4)
    for i in range(N_STATE):
        y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    # Move a pressure undershoot into the pocket, and a pocket overfill back into pressure, at
    # the chamber's capacitance, so the oil volume is conserved across the floor.
    volume = prm[P_V0] + prm[P_AA] * min(max(y[SX], 0.0), prm[P_STROKE])
    p_floor = prm[P_PCAV]
    capacitance = volume / mixture_bulk_modulus(p_floor, prm[P_E], prm[P_AIR])
    if y[SP] < p_floor:
        y[SVOID] += capacitance * (p_floor - y[SP])
        y[SP] = p_floor
    if y[SVOID] < 0.0:
        y[SP] = p_floor - y[SVOID] / capacitance
        y[SVOID] = 0.0


@njit(cache=True)
def _to_event(y: FloatArray, dy: FloatArray, step: float, shortest: float,
              prm: FloatArray) -> float:
    """Shorten a step to end just past the predicted start or end of a vapour pocket [s].

    The pocket's equations switch there; a step across the switch would be first-order
    accurate, one that ends on it keeps the fourth order of the rest of the step.
    """
    if y[SVOID] > 0.0:
        if dy[SVOID] < 0.0:
            until = -y[SVOID] / dy[SVOID]
            if until < step:
                return min(step, max(until * (1.0 + 1e-6), shortest))
    elif dy[SP] < 0.0 and y[SP] > prm[P_PCAV]:
        until = (y[SP] - prm[P_PCAV]) / -dy[SP]
        if until < step:
            return min(step, max(until * (1.0 + 1e-6), shortest))
    return step


@njit(cache=True)
def _advance(y: FloatArray, span: float, h_max: float, stiff_limit: float, n_drive: float,
             f_load: float, prm: FloatArray, work: FloatArray) -> None:
    """Advance y over ``span`` [s] under held inputs on a grid of RK4 steps of at most h_max.

    A grid step whose :func:`_stiffness` times its length exceeds ``stiff_limit`` is cut into
    equal steps that keep within it (the stiff passages, relief and free mode, only open in
    short events, so the rest of the time runs at the long step), and a step is cut where a
    vapour pocket starts or ends (:func:`_to_event`).
    """
    k1, k2, k3, k4, tmp = work[0], work[1], work[2], work[3], work[4]
    steps = max(1, math.ceil(span / h_max - 1e-9))
    h = span / steps
    shortest = 1e-3 * h
    for _ in range(steps):
        remaining = h
        while remaining > 1e-9 * h:
            _rhs(y, n_drive, f_load, prm, k1)
            pieces = max(1, math.ceil(_stiffness(y, k1, h, prm) * h / stiff_limit))
            step = _to_event(y, k1, min(remaining, h / pieces), shortest, prm)
            _rk4_step(y, step, n_drive, f_load, prm, k1, k2, k3, k4, tmp)
            remaining -= step


@njit(cache=True)
def _run(y0: FloatArray, prm: FloatArray, closed_loop: bool, x_ref: FloatArray,
         v_ref: FloatArray, command_in: FloatArray, f_load: FloatArray,
         position_noise: FloatArray, gains: FloatArray, period: float, h_max: float,
         stiff_limit: float, delay: float, history: FloatArray, states: FloatArray,
         commands: FloatArray) -> None:
    """Simulate the sampled loop; write the state at each sample time and the commands sent.

    A command sent at sample k acts on the drive from ``k period + delay``: within a period
    the drive switches once, ``shift`` after its start, so the period is integrated in two
    parts and the delay is exact. ``history`` holds the commands sent before t = 0, the last
    one just before (at least one).
    """
    y = y0.copy()
    work = np.empty((5, N_STATE))
    kp, kd, kff = gains[0], gains[1], gains[2]
    limit = prm[P_NMAX]
    lag = math.floor(delay / period + 1e-9)
    shift = delay - lag * period
    if shift < 1e-12:
        shift = 0.0
    x_meas_last = y[SX] + position_noise[0]
    for k in range(x_ref.shape[0]):
        for i in range(N_STATE):
            states[k, i] = y[i]
        if closed_loop:
            x_meas = y[SX] + position_noise[k]
            v_meas = (x_meas - x_meas_last) / period
            x_meas_last = x_meas
            u = kff * v_ref[k] + kp * (x_ref[k] - x_meas) + kd * (v_ref[k] - v_meas)
            commands[k] = min(max(u, -limit), limit)
        else:
            commands[k] = command_in[k]
        for part in range(2):
            source = k - lag - 1 + part  # the older command acts until the shift
            span = shift if part == 0 else period - shift
            if span <= 0.0:
                continue
            if source >= 0:
                drive = commands[source]
            else:
                drive = history[max(history.shape[0] + source, 0)]
            _advance(y, span, h_max, stiff_limit, drive, f_load[k], prm, work)


def check_effects(params: HasParameters, effects: Mapping[str, float]) -> dict[str, float]:
    """Return the effects as floats after checking names and sizes.

    Raises
    ------
    ValueError
        On an unknown effect, a negative or non-finite size, or a crack pressure not below the
        relief setting.

    """
    checked = {}
    for name, size in effects.items():
        if name not in EFFECTS:
            msg = f'unknown effect {name!r}; expected one of {EFFECTS}'
            raise ValueError(msg)
        value = float(size)
        if not (math.isfinite(value) and value >= 0.0):
            msg = f'effect {name} must be finite and not negative, got {size!r}'
            raise ValueError(msg)
        checked[name] = value
    if checked.get('relief_valve', 0.0) >= params.relief_pressure:
        msg = 'relief_valve crack pressure must lie below relief_pressure'
        raise ValueError(msg)
    if checked.get('entrained_air', 0.0) >= 1.0:
        msg = 'entrained_air is a volume fraction below 1'
        raise ValueError(msg)
    return checked


def holding_speed(params: HasParameters, effects: Mapping[str, float], pressure: float) -> float:
    """Return the motor speed [rad/s] that holds ``pressure`` [Pa] at rest, valve engaged.

    Parameters
    ----------
    params : HasParameters
        Plant parameters.
    effects : Mapping[str, float]
        Effect sizes by name (leakage, crack and dead zone count).
    pressure : float
        Rodless-chamber pressure [Pa].

    """
    prm = _pack(params, check_effects(params, effects))
    y = np.array([0.0, 0.0, pressure, 0.0, 1.0, 0.0])
    loss = -_net_flow(y, prm)  # all leakage and relief flow at n = 0, v = 0, s = 1
    speed = loss / prm[P_DP]
    if prm[P_NDZ] > 0.0 and speed != 0.0:
        speed += math.copysign(prm[P_NDZ], speed)
    return float(speed)


def spool_target(params: HasParameters, motor_speed: float, pressure: float,
                 spool: float) -> float:
    """Return the spool position [-] the compact valve moves to (paper 2.3.3), 1 assist.

    The spools are pushed by the pressure at the valve's inlet. While the valve is free the
    turning pump builds it, so the target rises with |n| from ``valve_release_speed`` to
    ``valve_engage_speed``; once the valve opens, the inlet sees the chamber through the
    opening s, so the target also rises with ``s p`` from ``valve_drop_pressure`` to
    ``valve_hold_pressure``. The larger of the two pushes (smoothsteps ``3 z^2 - 2 z^3``): a
    loaded valve stays in assist while the motor passes through zero, and springs back to free
    once the motor has stopped and the pressure has gone.

    Parameters
    ----------
    params : HasParameters
        Plant parameters.
    motor_speed : float
        Motor speed n [rad/s].
    pressure : float
        Rodless-chamber gauge pressure p [Pa].
    spool : float
        Spool position s [-].

    """
    return float(_spool_target(motor_speed, pressure, spool, _pack(params, {})))


def feedforward_gain(params: HasParameters) -> float:
    """Return the velocity feedforward 1 / K, K = D_p / A_A [(rad/s) per (m/s)] (no leakage)."""
    return params.flow_area / params.pump_displacement


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`, one row per sample.

    Attributes
    ----------
    clean : dict[str, np.ndarray]
        The :data:`COLUMNS` without sensor noise (the command is what was sent).
    noisy : dict[str, np.ndarray]
        The same columns as measured.
    states : np.ndarray
        Plant state ``[x, v, p, n, s, void]`` at each sample, shape (K, 6) [SI].
    effects : dict[str, float]
        The effects as applied.

    """

    clean: dict[str, FloatArray]
    noisy: dict[str, FloatArray]
    states: FloatArray
    effects: dict[str, float]

    @property
    def velocity(self) -> FloatArray:
        """Cylinder velocity at each sample [m/s]."""
        return self.states[:, SV]

    @property
    def spool(self) -> FloatArray:
        """Spool position at each sample [-] (1 assist, 0 free)."""
        return self.states[:, SS]


def rest_state(params: HasParameters, effects: Mapping[str, float], position: float,
               load_force: float) -> FloatArray:
    """Return the state at rest at ``position`` [m] holding ``load_force`` [N], valve engaged.

    The pressure is ``load_force / A_A`` (not below the cavitation floor) and the motor turns at
    :func:`holding_speed`.

    Parameters
    ----------
    params : HasParameters
        Plant parameters.
    effects : Mapping[str, float]
        Effect sizes by name.
    position : float
        Cylinder extension [m].
    load_force : float
        Load force [N], positive pushing the rod in.

    Returns
    -------
    np.ndarray
        ``[x, v, p, n, s, void]``.

    """
    pressure = max(load_force / params.area_a, params.cavitation_pressure)
    return np.array([position, 0.0, pressure, holding_speed(params, effects, pressure), 1.0,
                     0.0])


def simulate(params: HasParameters, effects: Mapping[str, float] | None = None, *,
             reference: ArrayLike | None = None, reference_velocity: ArrayLike | None = None,
             command: ArrayLike | None = None, load_force: ArrayLike = 0.0,
             noise: Mapping[str, float] | None = None, seed: int = 0,
             period: float = 1.0 / SAMPLE_RATE, substeps: int = SUBSTEPS,
             stiff_limit: float = STIFF_LIMIT, gains: tuple[float, float, float] | None = None,
             initial_position: float | None = None, initial_state: ArrayLike | None = None,
             past_commands: ArrayLike | None = None) -> Simulation:
    """Simulate the truth plant, closed loop on ``reference`` or open loop on ``command``.

    By default the plant starts at rest holding the first load force (:func:`rest_state`): in
    closed loop at the position where the first PD command equals the holding speed, so there
    is no start transient; in open loop at mid stroke. Commands sent before t = 0 (seen through
    a transport delay) equal the holding speed unless ``past_commands`` are given.

    Parameters
    ----------
    params : HasParameters
        Plant parameters (SI); ``params.effects`` is ignored.
    effects : Mapping[str, float] or None
        Effect sizes by name (:data:`EFFECTS`), in the units of the module docstring.
    reference, reference_velocity : array_like or None
        Cylinder position reference [m] and its derivative [m/s] at each sample (closed loop).
        The velocity defaults to the central difference of the reference.
    command : array_like or None
        Motor speed command at each sample [rad/s] (open loop), instead of a reference.
    load_force : array_like
        Load force [N] at each sample (or one value), positive pushing the rod in.
    noise : Mapping[str, float] or None
        Noise std by :data:`NOISE_RANGES` key; missing keys mean no noise.
    seed : int
        Seed of the noise generator.
    period : float
        Sample period [s].
    substeps : int
        RK4 steps per sample outside stiff events (the longest step is period / substeps).
    stiff_limit : float
        Largest product of step and fastest rate; stiff events take shorter steps.
    gains : tuple of float or None
        ``(kp, kd, kff)``; default ``(KP, KD, feedforward_gain(params))``.
    initial_position : float or None
        Initial extension [m] of the rest state.
    initial_state : array_like or None
        Full initial state ``[x, v, p, n, s, void]`` instead of a rest state.
    past_commands : array_like or None
        Commands sent before t = 0 [rad/s], oldest first, one per sample.

    Returns
    -------
    Simulation
        Noise-free and noisy columns and the states (the reference column is NaN in open
        loop).

    """
    applied = check_effects(params, effects or {})
    if (reference is None) == (command is None):
        msg = 'give either a reference (closed loop) or a command (open loop)'
        raise ValueError(msg)
    drive = np.asarray(reference if command is None else command, dtype=float)
    samples = drive.shape[0]
    loads = np.broadcast_to(np.asarray(load_force, dtype=float), (samples,)).copy()
    rng = np.random.default_rng(seed)
    levels = dict(noise or {})
    # Fixed draw order, so the same seed gives the same noise whatever the levels.
    draws = {name: rng.standard_normal(samples) * levels.get(name.removesuffix('_b'), 0.0)
             for name in ('position', 'pressure', 'pressure_b', 'motor_speed', 'load_force')}
    kp, kd, kff = gains or (KP, KD, feedforward_gain(params))
    closed = command is None
    if closed:
        x_ref = drive
        v_ref = (np.gradient(x_ref, period) if reference_velocity is None
                 else np.asarray(reference_velocity, dtype=float))
        command_in = np.zeros(samples)
    else:
        x_ref = np.full(samples, np.nan)
        v_ref = np.zeros(samples)
        command_in = drive
    if initial_state is not None:
        y0 = np.array(initial_state, dtype=float)
    else:
        y0 = rest_state(params, applied, params.stroke / 2.0, loads[0])
        if initial_position is not None:
            y0[SX] = initial_position
        elif closed:
            # The first command (measured velocity 0) then equals the holding speed.
            y0[SX] = x_ref[0] - (y0[SN] - (kff + kd) * v_ref[0]) / kp
    history = (np.array([y0[SN]]) if past_commands is None or len(past_commands) == 0
               else np.array(past_commands, dtype=float))
    states = np.empty((samples, N_STATE))
    commands = np.empty(samples)
    _run(y0, _pack(params, applied), closed, np.ascontiguousarray(x_ref),
         np.ascontiguousarray(v_ref), np.ascontiguousarray(command_in), loads,
         draws['position'], np.array([kp, kd, kff]), period, period / substeps, stiff_limit,
         applied.get('transport_delay', 0.0), history, states, commands)
    if not np.all(np.isfinite(states)):
        msg = 'the truth plant diverged'
        raise FloatingPointError(msg)
    clean = {
        'time': np.arange(samples) * period,
        'motor_speed_command': commands,
        'position': states[:, SX].copy(),
        'reference': x_ref,
        'pressure_a': states[:, SP].copy(),
        'pressure_b': np.zeros(samples),
        'motor_speed': states[:, SN].copy(),
        'load_force': loads,
    }
    noisy = {
        **clean,
        'position': clean['position'] + draws['position'],
        'pressure_a': clean['pressure_a'] + draws['pressure'],
        'pressure_b': draws['pressure_b'],
        'motor_speed': clean['motor_speed'] + draws['motor_speed'],
        'load_force': clean['load_force'] + draws['load_force'],
    }
    return Simulation(clean, noisy, states, applied)


# --- References and loads -----------------------------------------------------------------


def _ramp(t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Smoothstep from 0 to 1 over RAMP_DURATION and its time derivative [1/s]."""
    u = np.clip(t / RAMP_DURATION, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u) / RAMP_DURATION


_GAIT: dict[str, GaitCycle] = {}


def sine_sum_reference(rng: np.random.Generator, t: FloatArray, stroke: float,
                       scale: float = 1.0) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sum of eight sines 0.2-5 Hz about mid stroke (paper 4.2, Fig. 13), and its load profile.

    One frequency is drawn log-uniformly in each of eight log-spaced bands, with a random
    phase; each sine has 15 mm/s of velocity amplitude, capped at 8 mm of position amplitude,
    so the sum stays within +-26 mm, 0.12 m/s and 1.2 m/s^2 (the load's weight keeps p_A
    positive against such accelerations). The load of a rig's load cylinder sweeps slowly (one
    cycle in 4-10 s).

    Parameters
    ----------
    rng : np.random.Generator
        Draws the frequencies and phases.
    t : np.ndarray
        Sample times [s].
    stroke : float
        Cylinder stroke [m].
    scale : float
        Factor on every excursion and velocity (:func:`rigs.motion_scale`, 1 on the bench).

    Returns
    -------
    tuple of np.ndarray
        Reference [m], its velocity [m/s] and the load profile in [0, 1].

    """
    edges = np.geomspace(0.2, 5.0, 9)
    freq = np.exp(rng.uniform(np.log(edges[:-1]), np.log(edges[1:])))
    phase = rng.uniform(0.0, 2.0 * math.pi, freq.size)
    omega = 2.0 * math.pi * freq
    amplitude = scale * np.minimum(8.0e-3, 15.0e-3 / omega)
    arg = np.outer(t, omega) + phase
    motion = np.sin(arg) @ amplitude
    motion_rate = np.cos(arg) @ (amplitude * omega)
    load_freq = math.exp(rng.uniform(math.log(0.1), math.log(0.25)))
    load_phase = rng.uniform(0.0, 2.0 * math.pi)
    profile = 0.5 * (1.0 - np.cos(2.0 * math.pi * load_freq * t + load_phase))
    ramp, ramp_rate = _ramp(t)
    return (stroke / 2.0 + ramp * motion, ramp_rate * motion + ramp * motion_rate, profile)


def walk_reference(rng: np.random.Generator, t: FloatArray, params: HasParameters,
                   scale: float = 1.0) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gait-like periodic cylinder trajectory at the paper's 0.85 Hz stride frequency.

    The shape is the joint's own: Winter's hip or knee angle over the gait cycle through the
    joint's linkage (exo_has_sim.gait and .kinematics, data and geometry only). It is centred
    at mid stroke and scaled to a peak velocity drawn in 0.08-0.12 m/s: at full size the
    project's linkages need 0.26-0.30 m/s, above the 0.2 m/s a loaded HAS can give. The gait
    phase at t = 0 is random. The load follows stance (0-60 % of the cycle from heel contact) as
    a sin^2 hump, zero in swing.

    Parameters
    ----------
    rng : np.random.Generator
        Draws the gait phase at t = 0 and the peak velocity.
    t : np.ndarray
        Sample times [s].
    params : HasParameters
        The joint (type, linkage, stroke).
    scale : float
        Factor on the drawn peak velocity (:func:`rigs.motion_scale`, 1 on the bench).

    Returns
    -------
    tuple of np.ndarray
        Reference [m], its velocity [m/s] and the load profile in [0, 1].

    """
    if 'winter' not in _GAIT:
        _GAIT['winter'] = load_gait_cycle()
    gait = _GAIT['winter']
    linkage = Linkage.from_parameters(params)
    phase0 = rng.uniform()
    peak_velocity = scale * rng.uniform(0.08, 0.12)
    grid = np.linspace(0.0, 1.0, 2001)

    def shape(phase: FloatArray) -> FloatArray:
        hip, knee = gait.angles_at(phase)
        angle = hip if params.joint_type == 'hip' else knee
        return np.asarray(linkage.position(angle, check=False), dtype=float)

    mean = float(np.mean(shape(grid[:-1])))
    rate = np.gradient(shape(grid), grid) * STRIDE_FREQUENCY
    scale = peak_velocity / float(np.max(np.abs(rate)))

    def motion(time: FloatArray) -> FloatArray:
        return scale * (shape(phase0 + STRIDE_FREQUENCY * time) - mean)

    step = 1.0e-4  # s, central difference of the smooth spline
    value = motion(t)
    value_rate = (motion(t + step) - motion(t - step)) / (2.0 * step)
    ramp, ramp_rate = _ramp(t)
    phase = (phase0 + STRIDE_FREQUENCY * t) % 1.0
    profile = np.where(phase < 0.6, np.sin(math.pi * phase / 0.6) ** 2, 0.0)
    return (params.stroke / 2.0 + ramp * value, ramp_rate * value + ramp * value_rate, profile)


def squat_reference(rng: np.random.Generator, t: FloatArray, stroke: float,
                    scale: float = 1.0) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Raised-cosine squats at 0.5 Hz (paper 5.2) from 15 mm below full extension.

    The depth is drawn in 50-90 mm (38-69 % of the 130 mm stroke; flexion shortens the
    cylinder), so the peak velocity is 79-141 mm/s. The load grows with the depth.

    Parameters
    ----------
    rng : np.random.Generator
        Draws the depth.
    t : np.ndarray
        Sample times [s].
    stroke : float
        Cylinder stroke [m].
    scale : float
        Factor on the depth and on the top's distance from full extension
        (:func:`rigs.motion_scale`, 1 on the bench).

    Returns
    -------
    tuple of np.ndarray
        Reference [m], its velocity [m/s] and the load profile in [0, 1].

    """
    depth = scale * rng.uniform(0.05, 0.09)
    omega = 2.0 * math.pi * SQUAT_FREQUENCY
    profile = 0.5 * (1.0 - np.cos(omega * t))
    top = stroke - scale * 0.015
    return top - depth * profile, -depth * 0.5 * omega * np.sin(omega * t), profile


# --- Seeded draws ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Draw:
    """One seeded data set of one HAS and how it was made.

    Attributes
    ----------
    seed : int
        Seed of ``numpy.random.default_rng`` that drew everything.
    effect : str
        ``'none'`` or one of :data:`EFFECTS`.
    size : float
        Size of the effect in its unit (module docstring), 0.0 for none.
    joint_type : str
        ``'hip'`` or ``'knee'``.
    excitation : str
        One of :data:`EXCITATIONS`.
    parameters : dict[str, float]
        Drawn plant values: bulk_modulus [Pa], pump_leakage [m^3/(s Pa)], damping [N s/m] and
        cylinder_leakage [m^3/(s Pa)] (kept at its nominal 0: with p_B = 0 it is
        indistinguishable from pump leakage in assist).
    load_mass : float
        Load mass [kg], part of the moving mass.
    noise : dict[str, float]
        Noise std by :data:`NOISE_RANGES` key [SI].
    load : dict[str, float]
        ``pressure_low`` and ``pressure_high``: static load pressures [Pa] the load force spans.
    period : float
        Sample period [s].
    columns : dict[str, np.ndarray]
        The :data:`COLUMNS` as measured.
    clean : dict[str, np.ndarray]
        The same without sensor noise.
    rig : Path or None
        Folder of the parameters files drawn around (None: the bench's, test/rigs.py).

    """

    seed: int
    effect: str
    size: float
    joint_type: str
    excitation: str
    parameters: dict[str, float]
    load_mass: float
    noise: dict[str, float]
    load: dict[str, float]
    period: float
    columns: dict[str, FloatArray]
    clean: dict[str, FloatArray]
    rig: Path | None = None

    @property
    def effects(self) -> dict[str, float]:
        """The effect as a mapping for :func:`simulate` (empty for none)."""
        return {} if self.effect == 'none' else {self.effect: self.size}


_NOMINAL: dict[tuple[str, Path | None], HasParameters] = {}


def nominal_parameters(joint_type: str, rig: Path | None = None) -> HasParameters:
    """Return the nominal parameter set of a joint type.

    From the bench's files (test/rigs.py), or those in the folder ``rig``.
    """
    if joint_type not in JOINT_TYPES:
        msg = f'joint_type must be one of {JOINT_TYPES}, got {joint_type!r}'
        raise ValueError(msg)
    if (joint_type, rig) not in _NOMINAL:
        _NOMINAL[(joint_type, rig)] = rig_parameters(joint_type, rig)
    return _NOMINAL[(joint_type, rig)]


def plant_parameters(draw: Draw) -> HasParameters:
    """Return the plant parameters a draw was simulated with."""
    return nominal_parameters(draw.joint_type, draw.rig).replace(load_mass=draw.load_mass,
                                                                 **draw.parameters)


def effect_size(effect: str, fraction: float) -> float:
    """Return the size of an effect at ``fraction`` in [0, 1] of its range.

    Parameters
    ----------
    effect : str
        ``'none'`` (size 0) or one of :data:`EFFECTS`.
    fraction : float
        Position in the range, on a log scale where :data:`EFFECT_RANGES` says so.

    """
    if effect == 'none':
        return 0.0
    low, high, spacing = EFFECT_RANGES[effect]
    if spacing == 'log':
        size = low * (high / low) ** fraction
    else:
        size = low + (high - low) * fraction
    return float(size)


def draw(seed: int, joint_type: str | None = None, *, effect: str | None = None,
         size: float | None = None, excitation: str | None = None, duration: float = 20.0,
         load_mass: float = 50.0, rig: Path | None = None) -> Draw:
    """Draw one data set from ``numpy.random.default_rng(seed)`` and simulate it.

    The generator always takes the same variates in the same order, and the excitation and
    the noise from sub-generators seeded from it, so forcing a choice (joint type, effect,
    size or excitation) leaves every other draw of the seed unchanged: ``draw(s,
    effect='none')`` is the effect-free twin of ``draw(s)``.

    Drawn: the joint type and the effect (uniform over their choices; ``'none'`` is one of
    seven), the size (uniform over its range, log-uniform where :data:`EFFECT_RANGES` says so),
    bulk_modulus, pump_leakage and damping (uniform within +-30 % of nominal), the excitation
    (uniform), the load's lowest and highest static pressure (uniform in
    :data:`LOAD_PRESSURE_LOW` and :data:`LOAD_PRESSURE_HIGH`), and the noise std (uniform in
    :data:`NOISE_RANGES`). The load force is ``A_A (p_low + (p_high - p_low) w(t))`` with the
    excitation's profile w in [0, 1]. Its floor (230-460 N, about the weight of the 50 kg load)
    keeps p_A positive against the load's accelerations and the damping of a fast retraction:
    the lowest in 40 effect-free draws of each excitation is 0.75 MPa (sine sum), 1.2 MPa
    (squat) and 0.14 MPa (walk, whose swing retracts at up to 0.12 m/s on the floor; with
    Coulomb friction, which then carries load as well, a walk draw can cavitate there, the
    valve held in assist by the turning motor). Its peaks (11.5-14 MPa, the hip's 1770 N design
    thrust and up to 78 % of the 18 MPa rating) pass every crack pressure of the relief_valve
    range, in every draw alike, so the load says nothing about the effect.

    Parameters
    ----------
    seed : int
        Seed.
    joint_type, effect, excitation : str or None
        Force a choice instead of drawing it.
    size : float or None
        Force the effect's size (ignored for none).
    duration : float
        Length of the data [s].
    load_mass : float
        Load mass [kg].
    rig : Path or None
        Folder of the parameters files to draw around (default: the bench's, test/rigs.py;
        e.g. ``rigs.SHIPPED_DIR``); the excitations shrink with its stroke
        (:func:`rigs.motion_scale`), the load keeps its pressures.

    Returns
    -------
    Draw
        The choices, the measured columns and the noise-free ones.

    """
    rng = np.random.default_rng(seed)
    u_joint, u_effect, u_size, u_excitation = rng.random(4)
    factors = rng.uniform(1.0 - PARAMETER_SPREAD, 1.0 + PARAMETER_SPREAD, len(DRAWN_PARAMETERS))
    p_low = rng.uniform(*LOAD_PRESSURE_LOW)
    p_high = rng.uniform(*LOAD_PRESSURE_HIGH)
    noise = {name: float(rng.uniform(*bounds)) for name, bounds in NOISE_RANGES.items()}
    excitation_seed, noise_seed = (int(s) for s in rng.integers(0, 2**63, size=2))

    joint_type = joint_type or JOINT_TYPES[int(u_joint * len(JOINT_TYPES))]
    effect = effect or EFFECT_CHOICES[int(u_effect * len(EFFECT_CHOICES))]
    if effect not in EFFECT_CHOICES:
        msg = f'effect must be one of {EFFECT_CHOICES}, got {effect!r}'
        raise ValueError(msg)
    excitation = excitation or EXCITATIONS[int(u_excitation * len(EXCITATIONS))]
    if excitation not in EXCITATIONS:
        msg = f'excitation must be one of {EXCITATIONS}, got {excitation!r}'
        raise ValueError(msg)
    chosen = (0.0 if effect == 'none' else float(size) if size is not None
              else effect_size(effect, u_size))
    nominal = nominal_parameters(joint_type, rig)
    scale = motion_scale(joint_type, rig)
    parameters = {name: float(getattr(nominal, name) * factor)
                  for name, factor in zip(DRAWN_PARAMETERS, factors, strict=True)}
    parameters['cylinder_leakage'] = float(nominal.cylinder_leakage)
    params = nominal.replace(load_mass=load_mass, **parameters)

    period = 1.0 / SAMPLE_RATE
    t = np.arange(round(duration * SAMPLE_RATE)) * period
    excitation_rng = np.random.default_rng(excitation_seed)
    if excitation == 'sine_sum':
        x_ref, v_ref, profile = sine_sum_reference(excitation_rng, t, params.stroke, scale)
    elif excitation == 'walk':
        x_ref, v_ref, profile = walk_reference(excitation_rng, t, params, scale)
    else:
        x_ref, v_ref, profile = squat_reference(excitation_rng, t, params.stroke, scale)
    load_force = params.area_a * (p_low + (p_high - p_low) * profile)
    effects = {} if effect == 'none' else {effect: chosen}
    result = simulate(params, effects, reference=x_ref, reference_velocity=v_ref,
                      load_force=load_force, noise=noise, seed=noise_seed, period=period)
    return Draw(seed=seed, effect=effect, size=chosen, joint_type=joint_type,
                excitation=excitation, parameters=parameters, load_mass=load_mass,
                noise=noise, load={'pressure_low': p_low, 'pressure_high': p_high},
                period=period, columns=result.noisy, clean=result.clean, rig=rig)


def write_csv(draw: Draw, path: str | Path) -> None:
    """Write a draw's measured columns as CSV: a header row, then one row per sample.

    Values are written with 17 significant digits, so they read back exactly.

    Parameters
    ----------
    draw : Draw
        The draw.
    path : str or Path
        File to write.

    """
    table = np.column_stack([draw.columns[name] for name in COLUMNS])
    np.savetxt(path, table, fmt='%.17g', delimiter=',', header=','.join(COLUMNS), comments='')
