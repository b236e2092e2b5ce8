"""Fit percentage, windows, the paper's transfer-function identification and residual tests."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.signal import cont2discrete, lfilter

from exo_has_sim.diagnosis.compare import (
    Span,
    effective_samples,
    fit_percent,
    horizon_samples,
    make_windows,
)
from exo_has_sim.diagnosis.residuals import Z99, autocorrelation, cross_correlation, signatures
from exo_has_sim.diagnosis.transfer import arx_third_order, identify_third_order
from exo_has_sim.errors import DiagnosisError, FitError

PERIOD = 0.005


def test_the_fit_of_a_perfect_model_is_100_and_of_the_mean_is_0():
    y = np.sin(np.linspace(0.0, 10.0, 500))
    assert fit_percent(y, y) == 100.0
    assert_allclose(fit_percent(y, np.full_like(y, y.mean())), 0.0, atol=1e-12)
    # Half the deviation from the mean left: 50 %.
    assert_allclose(fit_percent(y, y.mean() + 0.5 * (y - y.mean())), 50.0, rtol=1e-12)
    with pytest.raises(DiagnosisError, match='constant measurement'):
        fit_percent(np.ones(5), np.ones(5))


def test_windows_interleave_validation_one_in_three_and_score_contiguous_samples():
    windows = make_windows(1000, 100, first=22, burn_in=20)
    assert windows.span.count == 9
    assert windows.validation.tolist() == [False, False, True] * 3
    scored = windows.span.scored()
    assert scored[0, 0] == 22 + 20 + 1
    assert np.all(np.diff(scored.ravel()) == 1)  # scored samples follow each other
    assert windows.validation_span.count == 3 and windows.estimation_span.count == 6
    assert scored.max() <= 999
    with pytest.raises(DiagnosisError, match='at least 3 are needed'):
        make_windows(250, 100)
    assert horizon_samples(0.5, PERIOD) == 100


def test_effective_samples_count_white_noise_fully_and_a_random_walk_as_its_windows():
    rng = np.random.default_rng(0)
    white = rng.standard_normal((20, 100))
    assert effective_samples(white) == pytest.approx(2000, rel=0.15)
    walk = np.cumsum(rng.standard_normal((20, 100)), axis=1)
    assert effective_samples(walk) < 200


def known_third_order():
    """Return a third-order G(s) with an integrator and two zeros, and its ZOH samples."""
    num = np.array([2.0, 60.0, 800.0])
    den = np.polymul([1.0, 0.0], [1.0, 12.0, 900.0])
    num_z, den_z, _ = cont2discrete((num, den), PERIOD, method='zoh')
    rng = np.random.default_rng(1)
    u = np.repeat(rng.standard_normal(600), 5)
    y = lfilter(num_z.ravel(), den_z, u)
    return num, den, num_z.ravel(), den_z, u, y


def test_the_paper_transfer_function_recovers_a_known_third_order_system():
    num, den, num_z, den_z, u, y = known_third_order()
    windows = make_windows(len(u), 100, first=5)
    model = identify_third_order(u, y, PERIOD, windows.estimation_span)
    # Discrete coefficients: (1 - z^-1)(1 + a1 z^-1 + a2 z^-2) and b1..b3.
    assert_allclose(np.polymul([1.0, -1.0], [1.0, *model.a]), den_z, atol=1e-9)
    assert_allclose(model.b, num_z[1:], rtol=1e-7)
    # Continuous G(s) through the inverse zero-order hold.
    assert model.method == 'zoh'
    assert_allclose(model.den, den, rtol=1e-6, atol=1e-6)
    assert_allclose(model.num, num, rtol=1e-6)
    assert_allclose(model.velocity_gain, 800.0 / 900.0, rtol=1e-6)
    assert_allclose(sorted(model.poles().real), sorted(np.roots(den).real), atol=1e-5)
    assert model.fit(u, y, windows.validation_span) == pytest.approx(100.0, abs=1e-6)


def test_the_regression_refuses_a_constant_input():
    with pytest.raises(FitError, match='constant'):
        arx_third_order(np.zeros(200), np.linspace(0.0, 1.0, 200), np.arange(10, 200))


def test_white_residuals_pass_the_whiteness_test_and_correlated_ones_fail():
    rng = np.random.default_rng(4)
    white = rng.standard_normal((10, 200))
    test = autocorrelation(white)
    assert_allclose(test.band, Z99 / math.sqrt(2000), rtol=1e-12)
    assert test.passed
    correlated = lfilter([1.0], [1.0, -0.8], white, axis=1)
    failed = autocorrelation(correlated)
    assert not failed.passed
    assert_allclose(failed.values[0], 0.8, atol=0.05)


def test_a_residual_that_follows_the_input_with_a_delay_peaks_at_that_lag():
    rng = np.random.default_rng(5)
    u = rng.standard_normal((10, 200))
    e = np.roll(u, 3, axis=1) + 0.1 * rng.standard_normal((10, 200))
    test = cross_correlation(e, u)
    assert test.lags[np.argmax(test.values)] == 3
    assert not test.passed
    independent = cross_correlation(rng.standard_normal((10, 200)), u)
    assert independent.outside < 0.1


def test_a_friction_step_in_the_pressure_residual_shows_in_the_velocity_sign_signature():
    rng = np.random.default_rng(6)
    n = 4000
    v = 0.05 * np.sin(np.linspace(0.0, 40.0, n))
    pressure_residual = -2e5 * np.sign(v) + 3e4 * rng.standard_normal(n)
    features = {'velocity': v, 'input': 100.0 * v, 'input_rate': np.gradient(100.0 * v),
                'since_reversal': np.zeros(n), 'pressure': np.full(n, 5e6),
                'pressure_rate': np.zeros(n)}
    rates = {'position': 1e-4 * rng.standard_normal(n)}
    found = {s.id: s for s in signatures(features, rates, {
        'position': np.zeros(n), 'pressure': pressure_residual}, PERIOD, 18e6)}
    assert found['velocity_sign'].statistic < -50.0
    assert abs(found['pressure_level'].statistic) < 4.0
    assert_allclose(found['velocity_sign'].means[0], 2e5, rtol=0.1)


def test_an_input_at_zero_throughout_leaves_out_the_signature_of_its_size():
    n = 400
    v = 1e-4 * np.random.default_rng(7).standard_normal(n)
    features = {'velocity': v, 'input': np.zeros(n), 'input_rate': np.zeros(n),
                'since_reversal': np.zeros(n)}
    rates = {'position': v}
    found = {s.id for s in signatures(features, rates, {'position': v}, PERIOD, None)}
    assert 'small_input' not in found and 'velocity_sign' in found


def test_a_span_scores_after_its_burn_in():
    span = Span(np.array([10, 50]), 5, burn_in=3)
    assert span.steps == 8
    assert span.scored().tolist() == [[14, 15, 16, 17, 18], [54, 55, 56, 57, 58]]


def _evaluation(level, spread, seed, windows=30, horizon=50):
    """Residuals of RMS about ``level`` in each window, varying by ``spread`` between them."""
    from exo_has_sim.diagnosis.fitting import Evaluation

    rng = np.random.default_rng(seed)
    scale = level * np.exp(rng.normal(0.0, spread, (windows, 1, 1)))
    predicted = scale * rng.normal(0.0, 1.0, (windows, horizon, 1))
    return Evaluation(predicted, np.zeros_like(predicted), np.ones(1))


def _score(effect, validation, reference):
    from exo_has_sim.diagnosis.fitting import Fit
    from exo_has_sim.diagnosis.selection import Score

    return Score((effect,), Fit({}, ()), validation, reference, 1)


def test_an_effect_that_predicts_as_well_as_the_named_one_is_called_indistinguishable():
    from exo_has_sim.diagnosis.selection import rivals

    reference = _evaluation(1.0, 0.1, 1)
    named = _score('relief_valve', _evaluation(0.3, 0.1, 2), reference)
    twin = _score('quadratic_leakage', _evaluation(0.3, 0.1, 3), reference)
    worse = _score('pump_deadzone', _evaluation(0.6, 0.1, 4), reference)
    useless = _score('entrained_air', _evaluation(1.0, 0.1, 5), reference)
    assert all(s.significant for s in (named, twin, worse)) and not useless.significant
    assert rivals([named, twin, worse, useless]) == ['quadratic_leakage']
    assert rivals([named, worse]) == []
    assert rivals([useless, named]) == []  # nothing named: no rival either
