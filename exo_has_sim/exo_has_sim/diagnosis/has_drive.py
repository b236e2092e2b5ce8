"""The HAS plant's drive over a record: the motor speed and the valve's spool, sample by sample.

The commands sent, delayed and held, pass through the model's motor speed loop (a first- or
second-order lag, :mod:`exo_has_sim.model`, discretised exactly for held inputs) and its valve
law, so that a window of :class:`~exo_has_sim.diagnosis.has_plant.HasPlant` starts from the
speed and spool that the commands before it left (with the candidate's transport delay).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter

from exo_has_sim import model
from exo_has_sim.diagnosis.plants import FloatArray
from exo_has_sim.parameters import HasParameters


def drive_histories(commands: FloatArray, lag: int, params: HasParameters, period: float,
                    time_constant: float, damping_ratio: float, speed_input: bool,
                    pressure: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Motor speed [rad/s], its rate [rad/s^2] and spool position [-] at every sample.

    Parameters
    ----------
    commands : FloatArray
        The motor speed commands [rad/s] sent at each sample, or the measured speed with
        ``speed_input``.
    lag : int
        Their delay [samples]: the first is held before the record.
    params : HasParameters
        The parameter set (top speed, circuit, valve).
    period : float
        Sample period [s].
    time_constant, damping_ratio : float
        The speed loop's [s] and [-]: first order for a ratio of 0, else second order.
    speed_input : bool
        Whether ``commands`` is the measured speed, which drives the pump as it is.
    pressure : FloatArray
        The rodless pressure [Pa] at each sample that the compact valve's law sees.

    Returns
    -------
    tuple of FloatArray
        Speed, rate and spool: the switched circuit's one-way motor follows the commands'
        size and its direction valve their sign (held within ``valve_release_speed``); the
        compact valve follows :func:`exo_has_sim.model.spool_target`, each through its
        first-order lag; the closed circuit has no valve to move (1).

    """
    tau, zeta = time_constant, damping_ratio
    command = np.concatenate((np.full(lag, commands[0]), commands[:len(commands) - lag]))
    command = np.clip(command, -params.motor_speed_max, params.motor_speed_max)
    one_way = params.circuit == 'switched'
    if speed_input:
        speed, rate = np.abs(command) if one_way else command, np.zeros(len(command))
    else:
        asked = np.abs(command) if one_way else command
        # The speed at sample k + 1 results from the command held over sample k.
        if zeta > 0.0:
            response, rate = second_order_response(asked, period, tau, zeta)
            rate = np.concatenate(([0.0], rate[:-1]))
        else:
            response, rate = first_order_response(asked, period, tau), np.zeros(len(asked))
        speed = np.concatenate(([asked[0]], response[:-1]))
    gain = 1.0 - math.exp(-period / params.valve_time_constant)
    spool = np.ones(len(speed))
    if one_way:
        s = 1.0
        for k in range(len(speed)):
            spool[k] = s
            if abs(command[k]) > params.valve_release_speed:
                s += gain * (math.copysign(1.0, command[k]) - s)
    elif params.circuit != 'closed':
        prm = model.pack(params)
        s = 1.0
        for k in range(len(speed)):
            spool[k] = s
            s += gain * (model.spool_target(speed[k], pressure[k], s, prm) - s)
    return speed, rate, spool


def second_order_response(values: FloatArray, period: float, time_constant: float,
                          damping_ratio: float) -> tuple[FloatArray, FloatArray]:
    """Response and rate at the samples of the second-order speed loop to a held input.

    ``n'' = w^2 (u - n) - 2 zeta w n'`` with ``w = 2 zeta / time_constant``
    (:func:`exo_has_sim.model.rhs`), from rest at the first input, discretised exactly for an
    input held over each period.
    """
    omega = 2.0 * damping_ratio / time_constant
    a = np.array([[0.0, 1.0], [-omega * omega, -2.0 * damping_ratio * omega]])
    b = np.array([0.0, omega * omega])
    augmented = np.zeros((3, 3))
    augmented[:2, :2], augmented[:2, 2] = a * period, b * period
    transition = expm(augmented)
    phi, gamma = transition[:2, :2], transition[:2, 2]
    state = np.array([values[0], 0.0])
    out = np.empty((len(values), 2))
    for k, u in enumerate(values):
        state = phi @ state + gamma * u
        out[k] = state
    return out[:, 0], out[:, 1]



def first_order_response(values: FloatArray, period: float, time_constant: float) -> FloatArray:
    """Response at the samples of a first-order lag to an input held over each period."""
    alpha = 1.0 - math.exp(-period / time_constant)
    out = lfilter([alpha], [1.0, alpha - 1.0], values, zi=[(1.0 - alpha) * values[0]])
    return np.asarray(out[0], dtype=float)
