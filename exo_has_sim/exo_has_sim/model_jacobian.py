"""The Jacobian of the HAS model's right-hand side, for the implicit integrators.

d(dy/dt)/dy of :func:`exo_has_sim.model.rhs` over the dynamic states: analytic for the paper's
HAS (:func:`analytic`), forward differences for the other circuits and options. The compiled
integrator (:mod:`exo_has_sim.integrator`, a W-method, of second order with either) factorises
it; scipy's Radau (:mod:`exo_has_sim.reference_solution`) steers its Newton iterations with
it. The tests check it against central differences.
"""

from __future__ import annotations

import math

import numpy as np

from exo_has_sim import model
from exo_has_sim.compiled import compiled
from exo_has_sim.model import (
    AIR_POLYTROPIC_EXPONENT,
    ATMOSPHERIC_PRESSURE,
    CAVITATION_TIME_CONSTANT,
    I_AA,
    I_AB,
    I_AE,
    I_AIR,
    I_B,
    I_CIRCUIT,
    I_CSTOP,
    I_DP,
    I_E,
    I_FB,
    I_FC,
    I_FS,
    I_GCRACK,
    I_GFREE,
    I_GREL,
    I_JM,
    I_KCHG,
    I_KSTOP,
    I_LC,
    I_LN,
    I_LN2,
    I_M,
    I_NDZ,
    I_PCAV,
    I_PCHG,
    I_PCRACK,
    I_PREL,
    I_SPEED_IN,
    I_STROKE,
    I_TAU_M,
    I_TAU_S,
    I_V0,
    I_VB,
    I_VEPS,
    I_VS,
    I_ZETA,
    N_DYNAMIC,
    N_STATE,
    NDOT,
    PA,
    PAPER,
    PB,
    VOID,
    VOID_THRESHOLD,
    VOL_COMPRESSION,
    VOL_FREE,
    VOL_LEAK,
    VOL_PUMP,
    VOL_RELIEF,
    N,
    S,
    V,
    X,
    effective_bulk_modulus,
    pump_speed,
    relief_flow,
    rhs,
    spool_drive,
)

#: Scale of each dynamic state's finite-difference step (x, v, p_A, n, s, void, n_dot, p_B):
#: the step is 1.5e-8 of the larger of the state and its scale.
_DIFFERENCE_SCALE = np.array([1e-3, 1e-3, 1e5, 1.0, 1e-3, 1e-9, 1.0, 1e5])


@compiled(model)
def _bulk_modulus_slope(p: float, prm: np.ndarray) -> float:
    """d(effective bulk modulus)/dp [Pa/Pa]."""
    air = prm[I_AIR]
    if air <= 0.0 or p + ATMOSPHERIC_PRESSURE <= 1.0e3:
        return 0.0
    p_abs = p + ATMOSPHERIC_PRESSURE
    kappa = AIR_POLYTROPIC_EXPONENT
    ratio = (ATMOSPHERIC_PRESSURE / p_abs) ** (1.0 / kappa)
    stiff = prm[I_E] / (kappa * p_abs)
    denominator = 1.0 + air * ratio * (stiff - 1.0)
    d_ratio = -ratio / (kappa * p_abs)
    d_denominator = air * (d_ratio * (stiff - 1.0) - ratio * stiff / p_abs)
    return float(-prm[I_E] * d_denominator / denominator ** 2)


@compiled(model)
def implicit_states(prm: np.ndarray) -> int:
    """Leading states an implicit integrator must solve for: p_B (the last) only if it moves.

    In the paper's circuit the rod side is the tank's and p_B stays constant, so its row of
    the Jacobian is zero and the implicit solve can leave it out (exactly).
    """
    return N_DYNAMIC - 1 if int(prm[I_CIRCUIT]) == PAPER else N_DYNAMIC


@compiled(model)
def analytic(prm: np.ndarray) -> bool:
    """Whether :func:`jacobian` is analytic for these parameters (the paper's HAS).

    So it is for the paper's circuit with its tank at atmospheric pressure, the motor's
    own speed loop and no torque limit; other parameter sets take finite differences.
    """
    return (int(prm[I_CIRCUIT]) == PAPER and prm[I_PCHG] == 0.0 and prm[I_KCHG] == 0.0
            and prm[I_JM] <= 0.0 and prm[I_SPEED_IN] <= 0.0)


@compiled(model)
def jacobian(y: np.ndarray, n_cmd: float, f_load: float, prm: np.ndarray,
             jac: np.ndarray) -> None:
    """Write d(dy/dt)/d(y[:N_DYNAMIC]) of one joint into ``jac`` (N_STATE x N_DYNAMIC).

    The analytic derivative of :func:`rhs` (one-sided at its kinks) where :func:`analytic`,
    else forward differences; for the implicit integrator, checked against central
    differences in the tests.
    """
    if analytic(prm):
        _analytic_jacobian(y, prm, jac)
        return
    base = np.empty(N_STATE)
    rhs(y, n_cmd, f_load, prm, base)
    _difference_jacobian(y, n_cmd, f_load, prm, base, jac)


@compiled(model)
def _difference_jacobian(y: np.ndarray, n_cmd: float, f_load: float, prm: np.ndarray,
                         base: np.ndarray, jac: np.ndarray) -> None:
    """Forward-difference d(dy/dt)/d(y[:N_DYNAMIC]) around ``base`` = dy/dt at y."""
    moved = y.copy()
    out = np.empty(N_STATE)
    for j in range(N_DYNAMIC):
        step = 1.5e-8 * max(abs(y[j]), _DIFFERENCE_SCALE[j])
        moved[j] = y[j] + step
        rhs(moved, n_cmd, f_load, prm, out)
        for i in range(N_STATE):
            jac[i, j] = (out[i] - base[i]) / step
        moved[j] = y[j]


@compiled(model)
def _analytic_jacobian(y: np.ndarray, prm: np.ndarray, jac: np.ndarray) -> None:
    """Write the analytic Jacobian of the paper's HAS (:func:`analytic`; see :func:`jacobian`)."""
    x, v, p, n, s = y[X], y[V], y[PA], y[N], y[S]
    for i in range(N_STATE):
        for j in range(N_DYNAMIC):
            jac[i, j] = 0.0
    stroke = prm[I_STROKE]
    inside = 0.0 <= x <= stroke
    volume = prm[I_V0] + prm[I_AA] * min(max(x, 0.0), stroke)
    modulus = effective_bulk_modulus(p, prm)
    capacitance = volume / modulus
    n_pump = pump_speed(n, prm)
    pump_slope = 1.0 if (prm[I_NDZ] <= 0.0 or abs(n) > prm[I_NDZ]) else 0.0
    leak_p = prm[I_LN] * p + prm[I_LN2] * p * abs(p)
    q_pump = s * prm[I_DP] * n_pump
    q_leak = s * leak_p + prm[I_LC] * p
    q_relief = relief_flow(p, prm)
    q_free = (1.0 - s) * prm[I_GFREE] * p
    q_net = q_pump - q_leak - q_relief - q_free - prm[I_AE] * v
    relief_slope = prm[I_GREL] if p > prm[I_PREL] else 0.0
    if prm[I_PCRACK] > 0.0 and prm[I_PCRACK] < p < prm[I_PREL]:
        relief_slope += prm[I_GCRACK]
    # d(flow)/d(state) for each flow, over (x, v, p, n, s).
    d_pump = (0.0, 0.0, 0.0, s * prm[I_DP] * pump_slope, prm[I_DP] * n_pump)
    d_leak = (0.0, 0.0, s * (prm[I_LN] + 2.0 * prm[I_LN2] * abs(p)) + prm[I_LC], 0.0, leak_p)
    d_relief = (0.0, 0.0, relief_slope, 0.0, 0.0)
    d_free = (0.0, 0.0, (1.0 - s) * prm[I_GFREE], 0.0, -prm[I_GFREE] * p)
    d_cap_x = prm[I_AA] / modulus if inside else 0.0
    d_cap_p = -volume * _bulk_modulus_slope(p, prm) / modulus ** 2
    pocket = y[VOID] > VOID_THRESHOLD or (p <= prm[I_PCAV] and q_net < 0.0)
    dp_pocket = (prm[I_PCAV] - p) / CAVITATION_TIME_CONSTANT
    for j in range(S + 1):
        d_net = d_pump[j] - d_leak[j] - d_relief[j] - d_free[j]
        if j == V:
            d_net -= prm[I_AE]
        d_cap = d_cap_x if j == X else (d_cap_p if j == PA else 0.0)
        if not pocket:
            jac[PA, j] = d_net / capacitance - q_net * d_cap / capacitance ** 2
            jac[VOL_COMPRESSION, j] = d_net
        else:
            d_dp = -1.0 / CAVITATION_TIME_CONSTANT if j == PA else 0.0
            d_compression = d_cap * dp_pocket + capacitance * d_dp
            jac[PA, j] = d_dp
            jac[VOL_COMPRESSION, j] = d_compression
            jac[VOID, j] = d_compression - d_net
        jac[VOL_PUMP, j] = d_pump[j]
        jac[VOL_LEAK, j] = d_leak[j]
        jac[VOL_RELIEF, j] = d_relief[j]
        jac[VOL_FREE, j] = d_free[j]
    # Force balance.
    d_force_x = 0.0
    d_force_v = -prm[I_B]
    if x < 0.0 and -prm[I_KSTOP] * x - prm[I_CSTOP] * v > 0.0:
        d_force_x, d_force_v = -prm[I_KSTOP], d_force_v - prm[I_CSTOP]
    elif x > stroke and -prm[I_KSTOP] * (x - stroke) - prm[I_CSTOP] * v < 0.0:
        d_force_x, d_force_v = -prm[I_KSTOP], d_force_v - prm[I_CSTOP]
    if prm[I_FC] > 0.0:
        peak = prm[I_FS] * math.exp(-(v / prm[I_VS]) ** 2)
        level = prm[I_FC] + peak
        t = math.tanh(v / prm[I_VEPS])
        d_level = peak * (-2.0 * v / prm[I_VS] ** 2)
        d_force_v -= d_level * t + level * (1.0 - t * t) / prm[I_VEPS]
    if prm[I_FB] > 0.0:
        t = math.tanh(v / prm[I_VB])
        d_force_v -= prm[I_FB] * (1.0 - t * t) / prm[I_VB]
    jac[X, V] = 1.0
    jac[V, X] = d_force_x / prm[I_M]
    jac[V, V] = d_force_v / prm[I_M]
    jac[V, PA] = prm[I_AA] / prm[I_M]
    jac[V, PB] = -prm[I_AB] / prm[I_M]
    zeta = prm[I_ZETA]
    if zeta > 0.0:
        omega = 2.0 * zeta / prm[I_TAU_M]
        jac[N, NDOT] = 1.0
        jac[NDOT, N] = -omega * omega
        jac[NDOT, NDOT] = -2.0 * zeta * omega
    else:
        jac[N, N] = -1.0 / prm[I_TAU_M]
        jac[NDOT, NDOT] = -1.0 / prm[I_TAU_M]
    _, driver, slope = spool_drive(n, p, s, prm)
    jac[S, S] = -1.0 / prm[I_TAU_S]
    if driver == 0:
        jac[S, N] = slope * (1.0 if n >= 0.0 else -1.0) / prm[I_TAU_S]
    else:
        jac[S, PA] = slope * s / prm[I_TAU_S]
        jac[S, S] += slope * p / prm[I_TAU_S]


@compiled(model)
def rhs_and_jacobian(y: np.ndarray, n_cmd: float, f_load: float, prm: np.ndarray,
                     dy: np.ndarray, jac: np.ndarray) -> None:
    """Evaluate :func:`rhs` and :func:`jacobian` together (the integrator needs both)."""
    rhs(y, n_cmd, f_load, prm, dy)
    if analytic(prm):
        _analytic_jacobian(y, prm, jac)
    else:
        _difference_jacobian(y, n_cmd, f_load, prm, dy, jac)
