"""The diagnosis report's plots read as a person would label them: real values, units."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim.diagnosis.report import _least_span, _plain, _prefixed


def test_a_flat_signal_is_drawn_with_its_own_values_and_no_offset():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    # A still window's motor speed: 7.27731 rad/s and a micro-radian-per-second drift, which
    # matplotlib's default labelled "1e-6+7.27731".
    speed = 7.27731 + 1e-7 * np.arange(100)
    fig, ax = plt.subplots()
    ax.plot(speed)
    _plain(ax)
    fig.canvas.draw()
    assert ax.yaxis.get_major_formatter().get_offset() == ''
    # Each tick is labelled with its value, in full.
    assert [float(text.get_text().replace('\N{MINUS SIGN}', '-'))
            for text in ax.get_yticklabels()] == pytest.approx(ax.get_yticks(), abs=1e-9)
    # And the window is drawn flat, within a span of the record's scale.
    _least_span(ax, speed, 30.0)
    low, high = ax.get_ylim()
    assert_allclose(high - low, 30.0)
    assert_allclose(0.5 * (low + high), 7.27731, atol=1e-5)
    plt.close(fig)


def test_an_axis_unit_takes_the_prefix_that_puts_its_values_between_1_and_1000():
    assert _prefixed('pressure residual [Pa]', np.array([-3.2e4, 1e3])) == \
        ('pressure residual [kPa]', 1e-3)
    assert _prefixed('position residual rate [m/s]', np.array([2.5e-4])) == \
        ('position residual rate [µm/s]', 1e6)
    assert _prefixed('lag [s]', np.array([0.0, 0.05])) == ('lag [ms]', 1e3)
    assert _prefixed('lag [s]', np.array([3e3])) == ('lag [s]', 1.0)  # never kiloseconds
    assert _prefixed('p / p_relief [-]', np.array([0.4])) == ('p / p_relief [-]', 1.0)
    assert _prefixed('velocity [m/s]', np.zeros(3)) == ('velocity [m/s]', 1.0)
