import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim import linear
from exo_has_sim.parameters import load_parameters

FREQUENCIES = np.logspace(-1, math.log10(20.0), 60)


@pytest.mark.parametrize('joint', ['hip', 'knee'])
@pytest.mark.parametrize('load', [0.0, 490.5, 1500.0])
def test_the_linearised_model_matches_eq12_from_01_to_20_hz_at_mid_stroke(joint, load):
    params = load_parameters(joint)
    reference = linear.eq12(params).frequency_response(FREQUENCIES)
    linearised = linear.linearize(params, load_force=load).frequency_response(FREQUENCIES)
    assert np.max(np.abs(np.abs(linearised) / np.abs(reference) - 1)) < 0.02
    assert np.max(np.abs(np.degrees(np.angle(linearised / reference)))) < 2.0


@pytest.mark.parametrize('flow_area', [None, 1.2e-4])
def test_eq13_and_eq14_are_the_coefficients_of_eq12(flow_area):
    params = load_parameters('hip')
    tf = linear.eq12(params, flow_area=flow_area)
    omega = linear.natural_frequency(params, flow_area=flow_area)
    assert_allclose(tf.den[2], omega ** 2, rtol=1e-12)
    assert_allclose(tf.num[0] / tf.den[2], linear.velocity_gain(params, flow_area),
                    rtol=1e-12)


def test_eq14_divides_by_the_rodless_area_and_as_printed_by_the_averaged_one():
    lossless = load_parameters('hip').replace(pump_leakage=0.0)
    assert_allclose(linear.velocity_gain(lossless),
                    lossless.pump_displacement / lossless.area_a, rtol=1e-12)
    printed = linear.velocity_gain(lossless, linear.averaged_flow_area(lossless))
    assert_allclose(printed, 2.0 * lossless.pump_displacement
                    / (lossless.area_a + lossless.area_b), rtol=1e-12)


def test_eq15_is_the_papers_identified_model():
    g = linear.eq15()
    assert_allclose(sorted(g.poles().real), [-26.21, -5.53, -0.24], rtol=1e-9)
    assert_allclose(g(0).real, 149.38 * 9.58 / (0.24 * 5.53 * 26.21), rtol=1e-12)


def test_a_pd_loop_has_unit_dc_gain_and_a_first_order_bandwidth():
    integrator = linear.TransferFunction(np.array([2.0]), np.array([1.0, 0.0]))
    closed = linear.pd_closed_loop(integrator, 5.0, 0.0)  # 10 / (s + 10)
    assert abs(closed(0)) == pytest.approx(1.0)
    assert linear.bandwidth(closed) == pytest.approx(10.0 / (2 * math.pi), rel=1e-3)
