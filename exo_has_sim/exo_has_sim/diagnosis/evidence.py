"""The record's evidence of the circuit and the motor, gathered before any effect is searched for.

Evidence a hydraulics engineer would use, whatever effect the record holds
(:mod:`~exo_has_sim.diagnosis.structure` says how it is weighed): the flow gain by direction,
the record's against the model's circuit's (:func:`direction_gain`, from the regression of
:func:`flow_gains`); a rod side that carries load in the paper's circuit
(:func:`rod_pressure`); a motor that falls short of settled commands (:func:`motor_shortfall`);
a force that resists the motion beyond what a seal can give (:func:`resisting_load`). Each is a
:class:`~exo_has_sim.diagnosis.findings.Finding`; :func:`evidence` gathers them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from exo_has_sim import model
from exo_has_sim.diagnosis.compare import Span
from exo_has_sim.diagnosis.effects import seal_friction_limit
from exo_has_sim.diagnosis.findings import Finding
from exo_has_sim.diagnosis.fitting import Z95, FloatArray
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.plants import WindowedModel, smooth

#: Largest ratio (or its inverse) of the record's flow gains by direction, retracting over
#: extending, to the circuit's own that a right structure leaves.
DIRECTION_RATIO = 1.2
#: Share of the pump speed's 95th percentile below which a sample does not count for the flow
#: gains (a pump that barely turns says little of its gain).
MOVING_SHARE = 0.15
#: Fewest samples each direction needs for the flow gain to be judged.
MIN_SAMPLES = 50
#: Speeds of a resisting force's fit, in brake velocities: tanh(2) = 0.96 of the level.
BRAKE_SATURATION = 2.0
#: Percentiles of a chamber's pressure where its loss in the flow gains' regression may bend.
LOSS_KNOTS = (50.0, 75.0, 90.0)
#: Time after the command last changed sign before a sample counts for the flow gains [s].
SETTLE_TIME = 0.05
#: Least rise [Pa] of the rod side above the charge pressure (95th percentile) that says it
#: carries load, and the least share of the rodless side's 95th percentile.
ROD_LOAD_PRESSURE = 1.0e6
ROD_LOAD_SHARE = 0.2
#: A settled command (within 5 % over five motor time constants) of at least this share of
#: the top speed, reached by less than :data:`MOTOR_REACHED` of it, falls short; more than
#: :data:`MOTOR_SHORT_SHARE` of such commands short is a finding.
MOTOR_COMMAND_SHARE = 0.1
MOTOR_REACHED = 0.8
MOTOR_SHORT_SHARE = 0.1


@dataclass(frozen=True)
class FlowGains:
    """The pump's flow gain by direction, from a regression of the rodless chamber's balance.

    ``A_A v = k_ext D_p n+ + k_ret D_p n- + c_ext + c_ret - sum_c (f_c(p_c) + C_c(p_c)
    dp_c/dt)`` over the samples in motion (``n+`` the pump speed where positive, else 0;
    ``n-`` likewise; ``c_ext``, ``c_ret`` a constant flow in each direction; c each chamber
    whose pressure is known): the share of the pump's flow each direction turns into the
    rodless chamber's motion, with what else the flow does fitted beside it. Each of these
    would otherwise pass for a flow gain that differs by direction: a loss ``f_c``, any
    piecewise-linear function of the pressure (a slope, and hinges at its knots), as a
    leakage that grows faster than linearly or a relief valve that cracks takes flow from the
    loaded chamber both ways (a cracked valve on the second truth plant had given 2.35); the
    constants, as a pump dead zone takes a fixed speed off each direction; the compliance
    ``C_c(p) = C_c0 + C_c1 / (p + p_atm)``, as free air in the oil is soft at low pressure
    (on the third truth plant both had given 0.74 to 0.83).

    Attributes
    ----------
    extending, retracting : float
        k_ext and k_ret [-].
    ratio : float
        k_ret / k_ext.
    error : float
        Standard error of the ratio's logarithm.
    samples : int
        Samples used.

    """

    extending: float
    retracting: float
    ratio: float
    error: float
    samples: int


def flow_gains(velocity: FloatArray, speed: FloatArray,
               pressures: Sequence[tuple[FloatArray, FloatArray, Sequence[float]]],
               area: float, displacement: float,
               mask: NDArray[np.bool_] | None = None) -> FlowGains | None:
    """Regress the rodless chamber's flow balance by direction (:class:`FlowGains`).

    ``pressures`` holds each known chamber pressure [Pa] with its rate [Pa/s], of the
    velocity's shape, and the knots [Pa] of its loss; ``mask`` the samples that may count.

    Samples count where the pump turns (above :data:`MOVING_SHARE` of its 95th percentile),
    whichever way the cylinder then moves: keeping only those where it moves the pump's way
    would drop the samples where a loss wins over the pump, and bias the direction that loses
    most; None when either direction has fewer than :data:`MIN_SAMPLES` of them or the
    regression is singular.
    """
    v, n = velocity.ravel(), speed.ravel()
    n_floor = MOVING_SHARE * float(np.percentile(np.abs(n), 95))
    use = np.abs(n) > n_floor
    if mask is not None:
        use &= mask.ravel()
    up, down = use & (n > 0.0), use & (n < 0.0)
    if np.count_nonzero(up) < MIN_SAMPLES or np.count_nonzero(down) < MIN_SAMPLES:
        return None
    columns = [np.where(up, displacement * n, 0.0), np.where(down, displacement * n, 0.0),
               up.astype(float), -down.astype(float)]
    for pressure, rate, knots in pressures:
        p = pressure.ravel()
        columns += [-p, -rate.ravel(),
                    -rate.ravel() / (np.maximum(p, 0.0) + model.ATMOSPHERIC_PRESSURE),
                    *(-np.maximum(p - knot, 0.0) for knot in knots)]
    design = np.column_stack(columns)[use]
    target = area * v[use]
    # Columns of flows [m^3/s], pressures [Pa] and pressure rates [Pa/s] differ by 1e13:
    # scaled to unit spread, the least squares does not lose the small ones.
    scale = np.std(design, axis=0)
    scale = np.where(scale > 0.0, scale, 1.0)
    scaled = design / scale
    try:
        coef, *_ = np.linalg.lstsq(scaled, target, rcond=None)
        residual = target - scaled @ coef
        dof = max(len(target) - design.shape[1], 1)
        covariance = np.linalg.pinv(scaled.T @ scaled) * float(residual @ residual) / dof
    except np.linalg.LinAlgError:
        return None
    coef = coef / scale
    covariance = covariance / np.outer(scale, scale)
    k_ext, k_ret = float(coef[0]), float(coef[1])
    if not (k_ext > 0.0 and k_ret > 0.0):
        return None
    error = math.sqrt(max(covariance[0, 0] / k_ext ** 2 + covariance[1, 1] / k_ret ** 2
                          - 2.0 * covariance[0, 1] / (k_ext * k_ret), 0.0))
    return FlowGains(k_ext, k_ret, k_ret / k_ext, error, int(np.count_nonzero(use)))


def pump_speed(plant: HasPlant) -> FloatArray:
    """Return the pump's speed at every sample: measured, or the commands through its loop."""
    m = plant.measurement
    if m.has('motor_speed'):
        return np.asarray(m.optional['motor_speed'], dtype=float)
    return plant.drive(0.0)[0]


def direction_gain(plant: HasPlant, span: Span) -> Finding | None:
    """Compare the record's flow gains by direction with the ratio the model's circuit gives.

    :func:`flow_gains` on the measured motion (velocity and pressure rate smoothed from the
    measured signals) over the windows, with the pump speed of :func:`pump_speed` and the
    samples :data:`SETTLE_TIME` after the command last changed sign (a valve switching, a
    delay, a speed logged with the side of the command sent: each blurs which side the pump
    feeds there) where a measured motor speed reaches :data:`MOTOR_REACHED` of its
    command (a motor at its torque limit stalls one way and not the other). The circuit's
    own ratio follows from which chamber the pump feeds: 1 for the paper's pump, which
    fills and empties the rodless chamber both ways whatever the load; A_A/A_B for the
    switched circuit, which feeds the rod side to retract; for the closed one, A_A/A_B where
    retracting presses the rod side (a load that resists both ways), else 1. A structure that
    routes the flow as the rig does gives the data's ratio,
    whatever its flow gain's error, which scales both directions alike. (A regression of the
    model's own prediction is no yardstick: off the rig it models, and even on it beside a
    hidden effect, it went from 0.4 to 2.) None where the regression is not possible, or the
    closed circuit's loaded side cannot be told.
    """
    m = plant.measurement
    period = m.period
    index = span.scored()
    speed = pump_speed(plant)[index]
    command = np.asarray(m.input, dtype=float)
    samples = np.arange(len(command))
    last_turn = np.zeros(len(command), dtype=int)  # the sample where the sign last changed
    turned = np.flatnonzero(np.diff(np.sign(command)) != 0) + 1
    last_turn[turned] = turned
    settled = ((samples - np.maximum.accumulate(last_turn)) * period >= SETTLE_TIME)[index]
    if m.has('motor_speed'):
        # Where the motor falls short of its command (a torque limit against the load) the
        # pump's flow and the motion part for a reason of the motor's, not the circuit's.
        settled &= (np.abs(m.optional['motor_speed'])
                    >= MOTOR_REACHED * np.abs(command))[index]
    area, displacement = plant.params.area_a, plant.params.pump_displacement
    measured = []
    for name in ('pressure_a', 'pressure_b'):
        if not m.has(name):
            continue
        pressure = smooth(m.optional[name], period)[index]
        knots = tuple(float(q) for q in np.percentile(pressure, LOSS_KNOTS))
        measured.append((pressure, smooth(m.optional[name], period, 1)[index], knots))
    data = flow_gains(smooth(m.position, period, 1)[index], speed, measured, area,
                      displacement, settled)
    if data is None:
        return None
    areas = plant.params.area_a / plant.params.area_b
    circuit = plant.params.circuit
    expected, why = 1.0, "the paper's pump fills and empties the rodless chamber both ways"
    if circuit == 'switched':
        expected, why = areas, 'its one-way pump feeds the rod side to retract'
    elif circuit == 'closed':
        if not (m.has('pressure_a') and m.has('pressure_b')):
            return None
        back = (speed < 0.0) & settled
        rod_loaded = float(np.median(m.optional['pressure_b'][index][back]
                                     - m.optional['pressure_a'][index][back])) > 0.0 \
            if np.any(back) else False
        expected, why = (areas, 'retracting presses the rod side, which its pump feeds') \
            if rod_loaded else (1.0, 'retracting presses the rodless side, which its pump '
                                     'empties')
    value = data.ratio / expected
    # Failing takes a ratio beyond the threshold by more than its own uncertainty: where the
    # motor stalls one way, the speeds that way say little (+-52 % against a torque limit).
    passed = abs(math.log(value)) <= math.log(DIRECTION_RATIO) + Z95 * data.error
    text = (f'flow gain by direction: per unit of pump flow the cylinder retracts '
            f'{data.ratio:.2f} times as fast as it extends (+-{1.96 * data.error:.1%}, '
            f"{data.samples} samples), where the model's circuit gives {expected:.2f} ({why}):"
            f' a ratio of {value:.2f} (a right structure: within {DIRECTION_RATIO:g} of 1)')
    if not passed and expected == 1.0 and abs(math.log(data.ratio / areas)) \
            < abs(math.log(data.ratio)):
        text += (f'; A_A/A_B is {areas:.2f}: retracting, the pump feeds the rod side (a '
                 "valve-switched or closed circuit), where the model's circuit feeds the "
                 'rodless one')
    return Finding('direction_gain', passed, value, DIRECTION_RATIO, text)


def resisting_force(plant: HasPlant) -> tuple[float, float] | None:
    """Estimate the level [N] of a force resisting the motion both ways, with its error.

    From the measured pressures: ``A_A p_A - A_B p_B - M a = F_0 + F_r sign(v) + B v`` over
    the samples in motion, by least squares; ``F_r`` is what resists (seal friction, a
    brake, a throttled load). None without ``pressure_a`` or with too little motion.
    """
    m = plant.measurement
    if not m.has('pressure_a'):
        return None
    period, params = m.period, plant.params
    v = smooth(m.position, period, 1)
    force = params.area_a * smooth(m.optional['pressure_a'], period) \
        - params.moving_mass * smooth(m.position, period, 2)
    if m.has('pressure_b'):
        force -= params.area_b * smooth(m.optional['pressure_b'], period)
    # Fast enough that the model's smoothed brake (tanh(v / v_b)) is within 4 % of its level.
    moving = np.abs(v) > max(MOVING_SHARE * float(np.percentile(np.abs(v), 95)),
                             BRAKE_SATURATION * params.brake_velocity)
    if np.count_nonzero(moving & (v > 0)) < MIN_SAMPLES \
            or np.count_nonzero(moving & (v < 0)) < MIN_SAMPLES:
        return None
    design = np.column_stack((np.ones(np.count_nonzero(moving)), np.sign(v[moving]),
                              v[moving]))
    target = force[moving]
    coef, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = target - design @ coef
    covariance = np.linalg.pinv(design.T @ design) * float(residual @ residual) \
        / max(len(target) - 3, 1)
    return float(coef[1]), math.sqrt(max(float(covariance[1, 1]), 0.0))


def rod_pressure(plant: HasPlant) -> Finding | None:
    """Say whether a measured rod-side pressure carries load, in the paper's circuit.

    The paper's circuit has the rod chamber open to the tank (its section 3.3, p_B = 0): a
    pressure there that rises well above the charge pressure is a chamber the pump or a
    valve pressurises, a circuit of another kind. None when it is not measured or the
    circuit already has a rod chamber.
    """
    m = plant.measurement
    if not m.has('pressure_b') or plant.rod_chamber:
        return None
    rise = float(np.percentile(m.optional['pressure_b'], 95)) - plant.params.charge_pressure
    threshold = ROD_LOAD_PRESSURE
    if m.has('pressure_a'):
        threshold = max(threshold, ROD_LOAD_SHARE * float(np.percentile(m.optional['pressure_a'],
                                                                        95)))
    passed = rise <= threshold
    text = (f'the rod side: pressure_b rises {rise * 1e-6:.2f} MPa above the tank (95th '
            f"percentile), where the paper's circuit has it at the tank "
            f'(at most {threshold * 1e-6:.2f} MPa)')
    if not passed:
        text += ': the rod chamber carries load, a chamber the circuit pressurises'
    return Finding('rod_pressure', passed, rise, threshold, text)


def motor_shortfall(plant: HasPlant) -> Finding | None:
    """Say whether the measured motor speed falls short of settled commands.

    A command counts as settled when it stayed within 5 % over the five motor time constants
    before; it should then be reached, unless the drive is at a torque or current limit.
    None without a measured motor speed, with the speed as the model's input, where the
    model has the motor's torque limit (the motor speed's fit then judges it), or with too
    few settled commands.
    """
    m = plant.measurement
    if not m.has('motor_speed') or plant.speed_input or plant.params.motor_inertia > 0.0:
        return None
    params = plant.params
    command = np.abs(np.clip(m.input, -params.motor_speed_max, params.motor_speed_max))
    speed = np.abs(m.optional['motor_speed'])
    settle = max(1, round(5.0 * params.motor_time_constant / m.period))
    if len(command) <= settle:
        return None
    rolling_max = np.array([np.max(command[max(0, k - settle):k + 1])
                            for k in range(len(command))])
    rolling_min = np.array([np.min(command[max(0, k - settle):k + 1])
                            for k in range(len(command))])
    settled = (command > MOTOR_COMMAND_SHARE * params.motor_speed_max) \
        & (rolling_max - rolling_min <= 0.05 * command)
    settled[:settle] = False
    if np.count_nonzero(settled) < MIN_SAMPLES:
        return None
    reached = speed[settled] / command[settled]
    short = float(np.mean(reached < MOTOR_REACHED))
    passed = short <= MOTOR_SHORT_SHARE
    worst = int(np.argmin(reached))
    text = (f'the motor: {short:.0%} of the settled commands were reached by less than '
            f'{MOTOR_REACHED:.0%} (median {float(np.median(reached)):.0%}; at worst '
            f'{speed[settled][worst]:.0f} rad/s against {command[settled][worst]:.0f} '
            'commanded)')
    if not passed:
        text += (': a torque or current limit, or a drive that cannot follow, which the '
                 "model's speed loop has not (--motor-speed-input judges the hydraulics "
                 'apart from it; motor_inertia in the parameters file models the limit)')
    return Finding('motor_shortfall', passed, short, MOTOR_SHORT_SHARE, text)


def resisting_load(plant: HasPlant) -> Finding | None:
    """Report a force resisting the motion beyond what a seal's friction can be (not gating).

    Such a force (:func:`resisting_force`) is a load, a brake or a throttled load cylinder; on
    a right structure the effect ``braking_load`` names it. None where it cannot be estimated
    or the parameter set already has a brake.
    """
    found = resisting_force(plant)
    if found is None or plant.params.brake_force > 0.0:
        return None
    level, error = found
    seal = seal_friction_limit(plant.params)
    passed = level - 3.0 * error <= seal
    text = (f'a force resists the motion both ways: {level:.0f} N (+-{1.96 * error:.0f}), '
            f'from the measured pressures')
    text += (f', within what seal friction can be here (up to {seal:.0f} N)' if passed else
             f', beyond what seal friction can be here (up to {seal:.0f} N): a brake or a '
             'throttled load')
    return Finding('resisting_load', passed, level, seal, text, gating=False)


def evidence(plant: WindowedModel, span: Span) -> list[Finding]:
    """Gather the record's evidence of the circuit and the motor, whatever effect it holds.

    ``span`` holds every window (for the flow gain by direction). Empty for a plant other
    than the HAS.
    """
    if not isinstance(plant, HasPlant):
        return []
    found = (direction_gain(plant, span), rod_pressure(plant), motor_shortfall(plant),
             resisting_load(plant))
    return [finding for finding in found if finding is not None]
