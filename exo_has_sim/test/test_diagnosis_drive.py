"""The drive's histories over a record (diagnosis.has_drive) against closed-form responses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim.diagnosis.has_drive import (
    drive_histories,
    first_order_response,
    second_order_response,
)
from exo_has_sim.parameters import load_parameters

PERIOD = 0.005  # s
SAMPLES = 400


def held_step() -> np.ndarray:
    """Return an input at rest at 0 over the first period, then 1 held: a unit step at T."""
    return np.concatenate(([0.0], np.ones(SAMPLES - 1)))


@pytest.mark.parametrize('damping_ratio', [0.3, 0.7, 0.95])
def test_a_second_order_loop_samples_the_textbook_step_response(damping_ratio):
    time_constant = 0.012  # s, so that w = 2 zeta / time_constant
    omega = 2.0 * damping_ratio / time_constant
    damped = omega * math.sqrt(1.0 - damping_ratio ** 2)
    # Row k is the state after input k, at (k + 1) T: k T after the step.
    t = PERIOD * np.arange(SAMPLES)
    decay = np.exp(-damping_ratio * omega * t)
    speed = 1.0 - decay * (np.cos(damped * t) + damping_ratio * omega / damped
                           * np.sin(damped * t))
    rate = decay * omega ** 2 / damped * np.sin(damped * t)
    response, response_rate = second_order_response(held_step(), PERIOD, time_constant,
                                                    damping_ratio)
    assert_allclose(response, speed, atol=1e-12)
    assert_allclose(response_rate, rate, atol=1e-9 * omega)


def test_a_first_order_lag_samples_the_exponential_step_response():
    time_constant = 0.02  # s
    t = PERIOD * np.arange(SAMPLES)
    assert_allclose(first_order_response(held_step(), PERIOD, time_constant),
                    1.0 - np.exp(-t / time_constant), atol=1e-12)


def test_a_switched_circuits_direction_valve_follows_the_sign_only_past_the_release_speed():
    params = dataclasses.replace(load_parameters('knee'), circuit='switched')
    release = params.valve_release_speed
    # Two samples past the release move the spool part of the way; inside it, it holds.
    commands = np.concatenate((np.full(2, -2.0 * release), np.full(50, -0.5 * release)))
    speed, _, spool = drive_histories(commands, 0, params, PERIOD, 0.01, 0.0, True,
                                      np.zeros(len(commands)))
    gain = 1.0 - math.exp(-PERIOD / params.valve_time_constant)
    # From 1 towards -1 by the gain each sample (row k before command k acts).
    moving = -1.0 + 2.0 * (1.0 - gain) ** np.arange(3)
    assert_allclose(spool[:3], moving, rtol=1e-12)
    assert -1.0 < spool[2] < 0.9
    assert np.all(spool[3:] == spool[2])
    assert_allclose(speed, np.abs(commands))  # a one-way motor turns by the command's size

