"""The nonlinear HAS model of Sun et al. (2021), Eqs. 2-8, with the effects it leaves out.

One joint's state is ``[x, v, p_A, n, s, void, n_dot, p_B]`` followed by five cumulative
volumes used to check the mass balance of the rodless chamber:

- ``x`` cylinder extension from its retracted end [m], ``v`` its velocity [m/s];
- ``p_A`` rodless-chamber gauge pressure [Pa]; ``p_B`` the rod chamber's [Pa], a state of the
  circuits that have one (below); in the paper's circuit the rod chamber is open to the elastic
  tank at atmospheric pressure (section 3.3: p_i = 0), so p_B stays 0;
- ``n`` motor (= pump) speed [rad/s], following the command through a first-order speed loop
  (the paper's), or a second-order one when ``motor_damping_ratio`` is set, whose rate
  ``n_dot`` [rad/s^2] is then a state too (zero for a first-order loop);
- ``s`` valve spool position [-]. In the paper's circuit the compact valve: 1 assist (pump to
  rodless chamber), 0 free (both chambers to the tank), pushed by the pressure at the valve's
  inlet: the pump's once the motor turns, the chamber's while in assist (section 2.3.3,
  :func:`spool_drive`). In the switched circuit the direction valve: +1 pump to A, -1 pump to B;
- ``void`` volume of the vapour pocket in the rodless chamber [m^3] (see below).

Flow balance of the rodless chamber, the paper's Eqs. 2, 4 and 6 with the rod side at the tank:
``(V_A + A_A x) / E * dp/dt = s D_p n_p - s (L_n p + L_n2 p|p|) - L_c p - A_A v - Q_relief
- (1 - s) G_free p``. The motion's flow is ``A_A v`` (Eq. 4, and
:attr:`~exo_has_sim.parameters.HasParameters.flow_area`), not the average ``(A_A + A_B) / 2``
of the paper's Eq. 10, so the linearisation at mid stroke is Eq. 12 and the steady velocity
K n is Eq. 14 with A_A in the place of that average (:mod:`exo_has_sim.linear`). Force
balance, Eq. 8 with the rod side, the load force, a known brake and end stops:
``(M_a + M_L) dv/dt = A_A p_A - A_B p_B - B v - F_friction - F_brake - F_load + F_stop``.

Circuits (:data:`exo_has_sim.parameters.CIRCUITS`; ``p_c`` the charge or tank pressure, an
accumulator's falling as the cylinder extends and takes up its oil, ``p_c - k_c (x - L / 2)``
with ``k_c`` the charge stiffness; ``G_r`` the return conductance; the rod chamber
``(V_B + A_B (stroke - x)) / E dp_B/dt = A_B v + Q_B``):

- ``paper``: as above, ``p_c`` the tank's (0 for the paper's atmospheric tank);
- ``two_chamber``: the paper's pump and compact valve, the rod chamber returning to the tank
  through a line, ``Q_B = L_c (p_A - p_B) - G_r (p_B - p_c)`` (the paper's Eq. 5 kept);
- ``closed``: the pump between the chambers, ``D_p n`` from B to A (its Eqs. 2-7 as written,
  Q_o = Q_A, Q_i = Q_B), leakage ``(L_n + L_c)(p_A - p_B)`` from A to B, cross-port relief
  valves, and a flow matching valve joining the lower-pressure chamber to ``p_c`` through
  ``G_r`` (the differential area's flow goes to or comes from there). The chamber under
  pressure sets the speed: ``D_p n / A_A`` with A loaded, ``D_p n / A_B`` with B loaded;
- ``switched``: a one-way pump (``n >= 0`` follows ``|command|``) whose flow the direction
  valve (``s``, following the command's sign) sends to A (``s = 1``) or B (``s = -1``), the
  other chamber draining to the accumulator at ``p_c`` through ``G_r``; the pump's leakage
  and relief valve act across its outlet and ``p_c``. Extending, A is fed (``D_p n / A_A``);
  retracting, B (``D_p n / A_B``): the flow gain differs by direction by A_A / A_B.

A cavitation floor holds ``p_A`` at the cavitation pressure while the balance would take it
lower: the missing volume becomes a vapour pocket, which a later net inflow must fill before the
pressure can rise again (``p_B`` is held at the floor without a pocket). The relief valve passes
``G_r (p - p_set)`` above its setting; the ``relief_valve`` effect adds an opening from a crack
pressure below it. All functions are compiled with numba and take the packed parameter vector of
:func:`pack`; the derivative of :func:`rhs` that implicit integrators need is in
:mod:`exo_has_sim.model_jacobian`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from exo_has_sim import parameters, valve
from exo_has_sim.compiled import compiled
from exo_has_sim.parameters import CIRCUITS, HasParameters
from exo_has_sim.valve import ValveMode

# State layout.
X, V, PA, N, S, VOID, NDOT, PB = 0, 1, 2, 3, 4, 5, 6, 7
VOL_PUMP, VOL_LEAK, VOL_RELIEF, VOL_FREE, VOL_COMPRESSION = 8, 9, 10, 11, 12
N_DYNAMIC = 8
N_STATE = 13

# Packed parameter layout.
(I_DP, I_NMAX, I_TAU_M, I_LN, I_LC, I_E, I_AA, I_AB, I_AE, I_STROKE, I_V0, I_M, I_B, I_PREL,
 I_GREL, I_GFREE, I_NENG, I_NREL, I_TAU_S, I_PCAV, I_KSTOP, I_CSTOP, I_FC, I_FS, I_VS, I_VEPS,
 I_NDZ, I_LN2, I_PCRACK, I_GCRACK, I_AIR, I_PHOLD, I_PDROP, I_ZETA, I_CIRCUIT, I_VB0, I_PCHG,
 I_GRET, I_JM, I_TMAX, I_ETA, I_SPEED_IN, I_FB, I_VB, I_KCHG) = range(45)
N_PACKED = 45

# Circuits (exo_has_sim.parameters.CIRCUITS) as the ints the compiled code branches on.
PAPER, TWO_CHAMBER, CLOSED, SWITCHED = (CIRCUITS.index(name) for name in
                                        ('paper', 'two_chamber', 'closed', 'switched'))

ATMOSPHERIC_PRESSURE = 101_325.0  # Pa
CAVITATION_TIME_CONSTANT = 1.0e-4  # s, relaxation of the pressure onto the cavitation floor
# A pocket smaller than this counts as none [m^3] (0.6 um of stroke): a solver's perturbation of
# an empty pocket must not switch the equations.
VOID_THRESHOLD = 1.0e-10
AIR_POLYTROPIC_EXPONENT = 1.4

# Valve modes (exo_has_sim.valve.ValveMode) as plain ints, which the compiled code returns.
# numba freezes these constants and the circuits' into the compiled functions, whose cache
# therefore goes stale with parameters.py and valve.py too (@compiled(parameters, valve)).
VALVE_FREE, VALVE_ASSIST, VALVE_RELIEF = int(ValveMode.FREE), int(ValveMode.ASSIST), \
    int(ValveMode.RELIEF)


def pack(params: HasParameters, speed_input: bool = False) -> np.ndarray:
    """Return the parameter vector the compiled functions take.

    ``speed_input``: the command is the measured motor speed, which drives the pump directly
    (the motor's own loop, limits and lag are then not modelled).
    """
    e = params.effects
    packed = np.empty(N_PACKED)
    packed[I_DP] = params.pump_displacement
    packed[I_NMAX] = params.motor_speed_max
    packed[I_TAU_M] = params.motor_time_constant
    packed[I_LN] = params.pump_leakage
    packed[I_LC] = params.cylinder_leakage
    packed[I_E] = params.bulk_modulus
    packed[I_AA] = params.area_a
    packed[I_AB] = params.area_b
    packed[I_AE] = params.flow_area
    packed[I_STROKE] = params.stroke
    packed[I_V0] = params.dead_volume
    packed[I_M] = params.moving_mass
    packed[I_B] = params.damping
    packed[I_PREL] = params.relief_pressure
    packed[I_GREL] = params.relief_conductance
    packed[I_GFREE] = params.free_conductance
    packed[I_NENG] = params.valve_engage_speed
    packed[I_NREL] = params.valve_release_speed
    packed[I_TAU_S] = params.valve_time_constant
    packed[I_PCAV] = params.cavitation_pressure
    packed[I_KSTOP] = params.end_stop_stiffness
    packed[I_CSTOP] = params.end_stop_damping
    packed[I_FC] = e.coulomb_friction
    packed[I_FS] = e.stribeck_friction
    packed[I_VS] = e.stribeck_velocity
    packed[I_VEPS] = e.friction_smoothing_velocity
    packed[I_NDZ] = e.pump_deadzone
    packed[I_LN2] = e.quadratic_leakage
    packed[I_PCRACK] = e.relief_crack_pressure
    packed[I_GCRACK] = e.relief_crack_conductance
    packed[I_AIR] = e.entrained_air
    packed[I_PHOLD] = params.valve_hold_pressure
    packed[I_PDROP] = params.valve_drop_pressure
    packed[I_ZETA] = params.motor_damping_ratio
    packed[I_CIRCUIT] = CIRCUITS.index(params.circuit)
    packed[I_VB0] = params.rod_dead_volume
    packed[I_PCHG] = params.charge_pressure
    packed[I_GRET] = params.return_conductance
    packed[I_JM] = params.motor_inertia
    packed[I_TMAX] = params.motor_torque_peak
    packed[I_ETA] = params.pump_mechanical_efficiency
    packed[I_SPEED_IN] = 1.0 if speed_input else 0.0
    packed[I_FB] = params.brake_force
    packed[I_VB] = params.brake_velocity
    packed[I_KCHG] = params.charge_stiffness
    return packed


def pack_joints(params: Sequence[HasParameters]) -> np.ndarray:
    """Return one :func:`pack` row per joint, shape (N, N_PACKED)."""
    return np.stack([pack(p) for p in params])


@compiled(parameters, valve)
def effective_bulk_modulus(p: float, prm: np.ndarray) -> float:
    """Bulk modulus of oil with entrained air at gauge pressure p [Pa] (air effect)."""
    air = prm[I_AIR]
    if air <= 0.0:
        return float(prm[I_E])
    p_abs = max(p + ATMOSPHERIC_PRESSURE, 1.0e3)
    kappa = AIR_POLYTROPIC_EXPONENT
    ratio = (ATMOSPHERIC_PRESSURE / p_abs) ** (1.0 / kappa)
    return float(prm[I_E] / (1.0 + air * ratio * (prm[I_E] / (kappa * p_abs) - 1.0)))


@compiled(parameters, valve)
def friction_force(v: float, prm: np.ndarray) -> float:
    """Seal friction [N], opposing v: Coulomb plus Stribeck peak, tanh-smoothed."""
    if prm[I_FC] <= 0.0:
        return 0.0
    level = prm[I_FC] + prm[I_FS] * math.exp(-(v / prm[I_VS]) ** 2)
    return float(level * math.tanh(v / prm[I_VEPS]))


@compiled(parameters, valve)
def pump_speed(n: float, prm: np.ndarray) -> float:
    """Speed at which the pump delivers to the cylinder [rad/s] (dead-zone effect)."""
    dz = prm[I_NDZ]
    if dz <= 0.0:
        return float(n)
    if n > dz:
        return float(n - dz)
    if n < -dz:
        return float(n + dz)
    return 0.0


@compiled(parameters, valve)
def relief_flow(p: float, prm: np.ndarray) -> float:
    """Flow through the safety valve to the tank [m^3/s]."""
    flow = prm[I_GREL] * max(p - prm[I_PREL], 0.0)
    if prm[I_PCRACK] > 0.0:
        flow += prm[I_GCRACK] * max(min(p, prm[I_PREL]) - prm[I_PCRACK], 0.0)
    return float(flow)


@compiled(parameters, valve)
def _smoothstep(z: float) -> tuple[float, float]:
    """Smoothstep of z clipped to [0, 1], and its derivative."""
    if z <= 0.0:
        return 0.0, 0.0
    if z >= 1.0:
        return 1.0, 0.0
    return z * z * (3.0 - 2.0 * z), 6.0 * z * (1.0 - z)


@compiled(parameters, valve)
def spool_drive(n: float, p: float, s: float, prm: np.ndarray) -> tuple[float, int, float]:
    """Spool position the system pressure drives the compact valve to (paper 2.3.3).

    The spool is pushed by the pressure at the valve's inlet: built by the turning pump while
    the valve is free (a function of motor speed n), and the chamber pressure p once the valve
    is in assist (the inlet is then open to the chamber), weighted by the spool opening s. So a
    loaded valve stays in assist while the motor passes through zero at a reversal; it falls to
    free mode once the motor stops and the pressure has gone, as the paper describes.

    Returns
    -------
    tuple[float, int, float]
        The target position; 0 if motor speed drives it, 1 if pressure does; and the
        derivative of the target by that term's argument (n, or the inlet pressure s p).

    """
    by_speed, d_speed = _smoothstep((abs(n) - prm[I_NREL]) / (prm[I_NENG] - prm[I_NREL]))
    span = prm[I_PHOLD] - prm[I_PDROP]
    by_pressure, d_pressure = _smoothstep((s * p - prm[I_PDROP]) / span)
    if by_pressure > by_speed:
        return by_pressure, 1, d_pressure / span
    return by_speed, 0, d_speed / (prm[I_NENG] - prm[I_NREL])


@compiled(parameters, valve)
def spool_target(n: float, p: float, s: float, prm: np.ndarray) -> float:
    """Spool position the compact valve moves to (see :func:`spool_drive`)."""
    return float(spool_drive(n, p, s, prm)[0])


@compiled(parameters, valve)
def brake_force(v: float, prm: np.ndarray) -> float:
    """Force of a known brake [N], opposing v (:attr:`HasParameters.brake_force`)."""
    if prm[I_FB] <= 0.0:
        return 0.0
    return float(prm[I_FB] * math.tanh(v / prm[I_VB]))


@compiled(parameters, valve)
def charge_pressure(x: float, prm: np.ndarray) -> float:
    """Pressure [Pa] of the charge line, tank or accumulator at cylinder extension x [m]."""
    stroke = prm[I_STROKE]
    return float(prm[I_PCHG] - prm[I_KCHG] * (min(max(x, 0.0), stroke) - 0.5 * stroke))


@compiled(parameters, valve)
def circuit_flows(y: np.ndarray, n_pump: float,
                  prm: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Flows of the circuit at state y and pump speed ``n_pump`` [rad/s] (module docstring).

    Returns
    -------
    tuple of float
        Into the rodless chamber from the pump [m^3/s]; out of it by leakage, by the relief
        valve, and to the tank or accumulator (the compact valve's free mode, the flow matching
        or direction valve); the net flow into the rod chamber but for its motion ``A_B v``;
        and the pressure rise across the pump [Pa], which loads the motor.

    """
    p, s, p_b = y[PA], y[S], y[PB]
    circuit = int(prm[I_CIRCUIT])
    p_c = charge_pressure(y[X], prm)
    d_p = prm[I_DP]
    if circuit == CLOSED:
        rise = p - p_b
        pump = d_p * pump_speed(n_pump, prm)
        leak = (prm[I_LN] + prm[I_LC]) * rise + prm[I_LN2] * rise * abs(rise)
        relief = relief_flow(rise, prm) - relief_flow(-rise, prm)
        # The flow matching valve joins the lower-pressure chamber to the charge line.
        loaded, _ = _smoothstep(rise / (prm[I_PHOLD] - prm[I_PDROP]) + 0.5)
        drain_a = (1.0 - loaded) * prm[I_GRET] * (p - p_c)
        into_b = -pump + leak + relief - loaded * prm[I_GRET] * (p_b - p_c)
        return pump, leak, relief, drain_a, into_b, rise
    if circuit == SWITCHED:
        to_a = min(max(0.5 * (1.0 + s), 0.0), 1.0)  # share of the pump's flow sent to A
        outlet = to_a * p + (1.0 - to_a) * p_b
        rise = outlet - p_c
        pump = d_p * pump_speed(max(n_pump, 0.0), prm)
        lost = prm[I_LN] * rise + prm[I_LN2] * rise * abs(rise)
        relieved = relief_flow(rise, prm)
        cross = prm[I_LC] * (p - p_b)
        drain_a = (1.0 - to_a) * prm[I_GRET] * (p - p_c)
        into_b = (1.0 - to_a) * (pump - lost - relieved) - to_a * prm[I_GRET] * (p_b - p_c) \
            + cross
        return to_a * pump, to_a * lost + cross, to_a * relieved, drain_a, into_b, rise
    # The paper's pump and compact valve (with the rod side a chamber of its own or not).
    rise = p - p_c
    pump = s * d_p * pump_speed(n_pump, prm)
    leak = s * (prm[I_LN] * rise + prm[I_LN2] * rise * abs(rise))
    into_b = 0.0
    if circuit == TWO_CHAMBER:
        cross = prm[I_LC] * (p - p_b)
        into_b = cross - prm[I_GRET] * (p_b - p_c)
    else:
        cross = prm[I_LC] * rise
    relief = relief_flow(rise, prm)
    free = (1.0 - s) * prm[I_GFREE] * rise
    return pump, leak + cross, relief, free, into_b, s * rise


@compiled(parameters, valve)
def motor_rate(command: float, n: float, rise: float, prm: np.ndarray) -> float:
    """Acceleration [rad/s^2] of a first-order speed loop, within the motor's torque limit.

    With a positive ``motor_inertia`` the drive cannot give more than ``motor_torque_peak``:
    the torque the loop asks, ``J (command - n) / tau`` and the pump's ``D_p rise / eta``, is
    clipped there. A one-way pump (the switched circuit) stops at zero speed.
    """
    rate = float((command - n) / prm[I_TAU_M])
    inertia = prm[I_JM]
    if inertia > 0.0:
        load = prm[I_DP] * rise / prm[I_ETA]
        rate = min(max(rate, (-prm[I_TMAX] - load) / inertia), (prm[I_TMAX] - load) / inertia)
    if int(prm[I_CIRCUIT]) == SWITCHED and n <= 0.0 and rate < 0.0:
        rate = 0.0
    return rate


@compiled(parameters, valve)
def rhs(y: np.ndarray, n_cmd: float, f_load: float, prm: np.ndarray,
        dy: np.ndarray) -> None:
    """Write dy/dt of one joint's state into ``dy``.

    Parameters
    ----------
    y : np.ndarray
        State (length N_STATE).
    n_cmd : float
        Motor speed command reaching the drive [rad/s] (after any transport delay); with
        ``speed_input`` packed (:func:`pack`), the motor speed itself. In the switched circuit
        its sign sets the direction valve and its size the one-way motor's speed.
    f_load : float
        External load force on the rod [N], positive pushing the cylinder to retract.
    prm : np.ndarray
        Packed parameters (:func:`pack`).
    dy : np.ndarray
        Output, length N_STATE.

    """
    x, v, p, n, s, p_b = y[X], y[V], y[PA], y[N], y[S], y[PB]
    circuit = int(prm[I_CIRCUIT])
    stroke = prm[I_STROKE]
    held = min(max(x, 0.0), stroke)
    volume = prm[I_V0] + prm[I_AA] * held
    capacitance = volume / effective_bulk_modulus(p, prm)
    limit = prm[I_NMAX]
    command = min(max(n_cmd, -limit), limit)
    if circuit == SWITCHED:
        command = abs(command)  # a one-way motor; the sign is the valve's
    speed_input = prm[I_SPEED_IN] > 0.0
    n_pump = command if speed_input else n
    q_pump, q_leak, q_relief, q_free, q_b, rise = circuit_flows(y, n_pump, prm)
    q_motion = prm[I_AE] * v
    q_net = q_pump - q_leak - q_relief - q_free - q_motion
    dp = q_net / capacitance
    dvoid = 0.0
    if y[VOID] > VOID_THRESHOLD or (p <= prm[I_PCAV] and q_net < 0.0):
        # Vapour pocket: the pressure is held at the floor (pulled back to it quickly after a
        # numerical overshoot) and the net flow grows or fills the pocket.
        dp = (prm[I_PCAV] - p) / CAVITATION_TIME_CONSTANT
        dvoid = capacitance * dp - q_net
    dp_b = 0.0
    if circuit != PAPER:
        rod_volume = prm[I_VB0] + prm[I_AB] * (stroke - held)
        dp_b = (q_b + prm[I_AB] * v) * effective_bulk_modulus(p_b, prm) / rod_volume
        if p_b <= prm[I_PCAV] and dp_b < 0.0:
            dp_b = (prm[I_PCAV] - p_b) / CAVITATION_TIME_CONSTANT
    force_stop = 0.0
    if x < 0.0:
        force_stop = max(-prm[I_KSTOP] * x - prm[I_CSTOP] * v, 0.0)
    elif x > stroke:
        force_stop = min(-prm[I_KSTOP] * (x - stroke) - prm[I_CSTOP] * v, 0.0)
    force = prm[I_AA] * p - prm[I_AB] * p_b - prm[I_B] * v - friction_force(v, prm) \
        - brake_force(v, prm) - f_load + force_stop
    dy[X] = v
    dy[V] = force / prm[I_M]
    dy[PA] = dp
    zeta = prm[I_ZETA]
    if speed_input:
        dy[N] = 0.0  # the measured speed drives the pump; the state is not used
        dy[NDOT] = 0.0
    elif zeta > 0.0:  # second order, the same low-frequency lag: omega = 2 zeta / tau
        omega = 2.0 * zeta / prm[I_TAU_M]
        dy[N] = y[NDOT]
        dy[NDOT] = omega * (omega * (command - n) - 2.0 * zeta * y[NDOT])
    else:
        dy[N] = motor_rate(command, n, rise, prm)
        dy[NDOT] = -y[NDOT] / prm[I_TAU_M]  # unused; stays at rest
    if circuit == SWITCHED:
        # The direction valve follows the command's sign; a command within the release speed
        # leaves it where it is.
        target = s
        if abs(n_cmd) > prm[I_NREL]:
            target = 1.0 if n_cmd > 0.0 else -1.0
        dy[S] = (target - s) / prm[I_TAU_S]
    elif circuit == CLOSED:
        dy[S] = (1.0 - s) / prm[I_TAU_S]  # no compact valve: the spool stays open
    else:
        dy[S] = (spool_target(n_pump, p, s, prm) - s) / prm[I_TAU_S]
    dy[VOID] = dvoid
    dy[PB] = dp_b
    dy[VOL_PUMP] = q_pump
    dy[VOL_LEAK] = q_leak
    dy[VOL_RELIEF] = q_relief
    dy[VOL_FREE] = q_free
    dy[VOL_COMPRESSION] = capacitance * dp


@compiled(parameters, valve)
def valve_mode(y: np.ndarray, prm: np.ndarray) -> int:
    """Valve mode of a state: relief when a safety valve passes flow, else assist or free.

    Only the paper's circuits have a free mode; the others are in assist unless relieving.
    """
    circuit = int(prm[I_CIRCUIT])
    if circuit == CLOSED:
        relieving = relief_flow(y[PA] - y[PB], prm) + relief_flow(y[PB] - y[PA], prm) > 0.0
    elif circuit == SWITCHED:
        to_a = min(max(0.5 * (1.0 + y[S]), 0.0), 1.0)
        relieving = relief_flow(to_a * y[PA] + (1.0 - to_a) * y[PB]
                                - charge_pressure(y[X], prm), prm) > 0.0
    else:
        relieving = relief_flow(y[PA] - charge_pressure(y[X], prm), prm) > 0.0
    if relieving:
        return VALVE_RELIEF
    if circuit in (CLOSED, SWITCHED):
        return VALVE_ASSIST
    return VALVE_ASSIST if y[S] >= 0.5 else VALVE_FREE


def initial_state(params: HasParameters, position: float, load_force: float = 0.0,
                  assist: bool = True) -> np.ndarray:
    """Return a state at rest at ``position`` [m] holding ``load_force`` [N].

    In assist the pressure carries the load and the motor turns just fast enough to replace the
    leakage; in free mode the pressure is zero (the load is then not held). A load so light that
    this speed is below ``valve_engage_speed`` (about 130 N on the hip) is not at rest: the
    spool drifts towards free mode and the load sinks, as with the real valve, whose motor must
    turn to keep the pressure that holds it in assist. In the circuits with a rod chamber of
    their own it starts at the charge pressure, and in the closed and switched circuits the
    motor stands (their valves hold the load).
    """
    y = np.zeros(N_STATE)
    y[X] = position
    charge = params.charge_pressure
    circuit = params.circuit
    if circuit != 'paper':
        y[PB] = charge
    if circuit in ('closed', 'switched'):
        y[PA] = max((load_force + params.area_b * charge) / params.area_a,
                    params.cavitation_pressure)
        y[S] = 1.0
        return y
    if assist:
        pressure = max((load_force + params.area_b * y[PB]) / params.area_a,
                       params.cavitation_pressure)
        rise = pressure - charge
        leak = params.pump_leakage * rise + params.cylinder_leakage * (pressure - y[PB]) \
            + params.effects.quadratic_leakage * rise * abs(rise)
        speed = leak / params.pump_displacement
        dz = params.effects.pump_deadzone
        speed += math.copysign(dz, speed) if dz and speed else 0.0
        y[PA] = pressure
        y[N] = speed
        y[S] = 1.0
    return y
