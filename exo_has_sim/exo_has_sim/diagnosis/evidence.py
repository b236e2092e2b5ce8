"""The record's evidence of the circuit and the motor, gathered before any effect is searched for.

Evidence a hydraulics engineer would use, whatever effect the record holds
(:mod:`~exo_has_sim.diagnosis.structure` says how it is weighed), the plainest first: a record
that moves past the parameters file's stroke (:func:`stroke_reach`); the flow gain by
direction, the record's against the model's circuit's (:func:`direction_gain`, from the
regression and the ratio of medians of :mod:`~exo_has_sim.diagnosis.flow_gains`); a rod side
that carries load in the paper's circuit (:func:`rod_pressure`); a motor that falls short of
settled commands (:func:`motor_shortfall`); a force that resists the motion beyond what a seal
can give (:func:`resisting_load`). Each is a
:class:`~exo_has_sim.diagnosis.findings.Finding` whose number a user can check by a direct
calculation on the samples, shown in its text; :func:`evidence` gathers them.
"""

from __future__ import annotations

import math

import numpy as np

from exo_has_sim.diagnosis.compare import Span
from exo_has_sim.diagnosis.effects import seal_friction_limit
from exo_has_sim.diagnosis.findings import Finding
from exo_has_sim.diagnosis.fitting import Z95, FloatArray
from exo_has_sim.diagnosis.flow_gains import (
    DIRECTION_RATIO,
    MIN_SAMPLES,
    MOVING_SHARE,
    direct_ratio,
    flow_gains,
    regression_doubt,
    within,
)
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.plants import WindowedModel, smooth

#: Share of the stroke by which the record's smoothed position may pass either end of the
#: parameters file's stroke (a cylinder pressed on its stop, a sensor's offset) before the file
#: is said not to describe the cylinder.
STROKE_MARGIN = 0.02
#: Least pump speed of a sample in the direct look at the flow gains, as a share of the
#: motor's top speed (the rig's engineers read theirs above 30 rad/s).
DIRECT_SPEED_SHARE = 0.1
#: Factor within which the regression must pin the ratio (95 %) for its figure to be given as
#: the rig's, rather than as a verdict the figure cannot refine.
PRECISE_RATIO = 1.1
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


def pump_speed(plant: HasPlant) -> FloatArray:
    """Return the pump's speed at every sample: measured, or the commands through its loop."""
    m = plant.measurement
    if m.has('motor_speed'):
        return np.asarray(m.optional['motor_speed'], dtype=float)
    return plant.drive(0.0)[0]


def direction_gain(plant: HasPlant, span: Span) -> Finding | None:
    """Compare the record's flow gains by direction with the ratio the model's circuit gives.

    :func:`~exo_has_sim.diagnosis.flow_gains.flow_gains` on the measured motion (velocity and
    pressure rate smoothed from the measured signals) over the windows, with the pump speed of
    :func:`pump_speed` and the samples :data:`SETTLE_TIME` after the command last changed sign
    (a valve switching, a delay, a speed logged with the side of the command sent: each blurs
    which side the pump feeds there) where a measured motor speed reaches :data:`MOTOR_REACHED`
    of its command (a motor at its torque limit stalls one way and not the other). The
    circuit's own ratio follows from which chamber the pump feeds: 1 for the paper's pump,
    which fills and empties the rodless chamber both ways whatever the load; A_A/A_B for the
    switched circuit, which feeds the rod side to retract; for the closed one, A_A/A_B where
    retracting presses the rod side (a load that resists both ways), else 1. A structure that
    routes the flow as the rig does gives the data's ratio, whatever its flow gain's error,
    which scales both directions alike. (A regression of the model's own prediction is no
    yardstick: off the rig it models, and even on it beside a hidden effect, it went from 0.4
    to 2.) None where the regression is not possible, or the closed circuit's loaded side
    cannot be told.
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
    velocity = smooth(m.position, period, 1)[index]
    data = flow_gains(velocity, speed, measured, area, displacement, settled)
    if data is None:
        return None
    # A pump that turns slowly against a loaded chamber loses much of its flow to leakage,
    # which the direct look does not take out: it counts only a tenth of the top speed and up.
    least_speed = DIRECT_SPEED_SHARE * plant.params.motor_speed_max
    direct = direct_ratio(velocity, speed, area, displacement, settled, least_speed)
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
    passed = within(data.ratio, data.error, expected)
    look = direct.sentence() if direct is not None else (
        f'no direct look: fewer than {MIN_SAMPLES} steady samples either way with the pump '
        f'above {least_speed:.3g} rad/s')
    text = (f'flow gain by direction: per unit of pump flow the cylinder retracts '
            f'{data.ratio:.2f} times as fast as it extends (regression, +-{Z95 * data.error:.1%}'
            f", {data.samples} samples; {look}), where the model's circuit gives "
            f'{expected:.2f} ({why}): a ratio of {value:.2f} (a right structure: within '
            f'{DIRECTION_RATIO:g} of 1)')
    doubt = regression_doubt(data, direct, areas)
    if doubt is None and passed and plant.window_load:
        # A loss at the loaded chamber's pressure slows the direction it loads: with the
        # pressure unknown, a rig whose pump feeds the rod side against a brake of 4.7 kN
        # read 1.05 (directly 1.10) for its A_A/A_B of 1.46.
        doubt = ("without pressure_a, a loss at the loaded chamber's pressure (a brake's, a "
                 "relief valve's) moves the ratio unseen by as much as the circuits differ "
                 f'(1 against A_A/A_B = {areas:.2f})')
    if doubt is not None and plant.window_load:
        doubt += '; record pressure_a to tell'
    if doubt is not None:
        # Undecided is not passed: the finding is reported, and decides nothing.
        text += (f'; but {doubt}: these data cannot tell the flow gain by direction, which '
                 'decides nothing')
        return Finding('direction_gain', False, value, DIRECTION_RATIO, text, gating=False)
    if Z95 * data.error > math.log(PRECISE_RATIO):
        text += (f'; the verdict stands with both, but these data cannot tell the ratio '
                 f'closer than +-{math.exp(Z95 * data.error) - 1.0:.0%}')
    if not passed and expected == 1.0 and abs(math.log(data.ratio / areas)) \
            < abs(math.log(data.ratio)):
        text += (f'; A_A/A_B is {areas:.2f}: retracting, the pump feeds the rod side (a '
                 "valve-switched or closed circuit), where the model's circuit feeds the "
                 'rodless one')
    return Finding('direction_gain', passed, value, DIRECTION_RATIO, text)


def _net_force(plant: HasPlant) -> tuple[FloatArray, FloatArray] | None:
    """Return the pressures' net force less inertia [N] and the velocity [m/s], in motion.

    The samples in motion are those fast enough that the model's smoothed brake
    (``tanh(v / v_b)``) is within 4 % of its level; None without ``pressure_a`` or with fewer
    than :data:`MIN_SAMPLES` such samples either way.
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
    moving = np.abs(v) > max(MOVING_SHARE * float(np.percentile(np.abs(v), 95)),
                             BRAKE_SATURATION * params.brake_velocity)
    if np.count_nonzero(moving & (v > 0)) < MIN_SAMPLES \
            or np.count_nonzero(moving & (v < 0)) < MIN_SAMPLES:
        return None
    return force[moving], v[moving]


def resisting_force(plant: HasPlant) -> tuple[float, float] | None:
    """Estimate the level [N] of a force resisting the motion both ways, with its error.

    From the measured pressures: ``A_A p_A - A_B p_B - M a = F_0 + F_r sign(v) + B v`` over
    the samples in motion (:func:`_net_force`), by least squares; ``F_r`` is what resists
    (seal friction, a brake, a throttled load). None without ``pressure_a`` or with too
    little motion.
    """
    found = _net_force(plant)
    return None if found is None else _resisting_fit(*found)


def _resisting_fit(target: FloatArray, v: FloatArray) -> tuple[float, float]:
    """Fit ``F_0 + F_r sign(v) + B v`` to the net force [N]; return F_r and its error [N]."""
    design = np.column_stack((np.ones(len(v)), np.sign(v), v))
    coef, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = target - design @ coef
    covariance = np.linalg.pinv(design.T @ design) * float(residual @ residual) \
        / max(len(target) - 3, 1)
    return float(coef[1]), math.sqrt(max(float(covariance[1, 1]), 0.0))


def stroke_reach(plant: HasPlant) -> Finding:
    """Say whether the record's positions lie within the parameters file's stroke.

    The plainest evidence of all: a cylinder that moves past the stroke the file gives is not
    the file's cylinder, whatever the fits say. The position, smoothed as the windows' initial
    states are, may pass either end by :data:`STROKE_MARGIN` of the stroke.
    """
    position = smooth(plant.measurement.position, plant.measurement.period)
    stroke = plant.params.stroke
    low, high = float(np.min(position)), float(np.max(position))
    margin = STROKE_MARGIN * stroke
    passed = -margin <= low and high <= stroke + margin
    beyond = max(high - stroke, -low, 0.0)
    text = (f'the stroke: the record moves from {low * 1e3:.1f} to {high * 1e3:.1f} mm from '
            f"the retracted end, where the parameters file's cylinder has a stroke of "
            f'{stroke * 1e3:.1f} mm')
    if not passed:
        text += (f': it passes an end by {beyond * 1e3:.1f} mm, so the file does not describe '
                 'this cylinder (state its stroke, bore and rod in the parameters file)')
    return Finding('stroke', passed, beyond, margin, text)


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
    found = _net_force(plant)
    if found is None or plant.params.brake_force > 0.0:
        return None
    force, v = found
    level, error = _resisting_fit(force, v)
    # The check a user can make: half the gap between the medians of the net pressure force
    # extending and retracting, with no damping or offset taken out.
    direct = 0.5 * float(np.median(force[v > 0.0]) - np.median(force[v < 0.0]))
    seal = seal_friction_limit(plant.params)
    passed = level - 3.0 * error <= seal
    text = (f'a force resists the motion both ways: {level:.0f} N (+-{Z95 * error:.0f}), '
            f'from the measured pressures (directly, half the gap between the median net '
            f'force A_A p_A - A_B p_B - M a extending and retracting: {direct:.0f} N)')
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
    found = (stroke_reach(plant), direction_gain(plant, span), rod_pressure(plant),
             motor_shortfall(plant), resisting_load(plant))
    return [finding for finding in found if finding is not None]
