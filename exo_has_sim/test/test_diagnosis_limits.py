"""Detection limits of a record (exo_has_sim.diagnosis.limits), judged by the selection's rules."""

from __future__ import annotations

import math

import numpy as np
import pytest

from exo_has_sim.diagnosis.limits import DetectionLimit, _named_over, ladder, refused_at

WINDOWS, HORIZON, OUTPUTS = 40, 100, 2
WEIGHTS = np.ones(OUTPUTS)


def noise(seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(WINDOWS, HORIZON, OUTPUTS))


def change_of(amplitude: float, seed: int = 2) -> np.ndarray:
    """Return a smooth change of the prediction in every window, as an effect makes."""
    rng = np.random.default_rng(seed)
    shape = np.sin(np.linspace(0.0, 3.0 * np.pi, HORIZON))[None, :, None]
    return amplitude * shape * rng.uniform(0.5, 1.5, size=(WINDOWS, 1, OUTPUTS))


def test_a_change_well_above_the_noise_is_named_and_one_within_it_is_not():
    r0 = noise()
    assert _named_over(change_of(1.0), r0, WEIGHTS, 1, [])
    assert not _named_over(change_of(0.05), r0, WEIGHTS, 1, [])


def test_the_named_share_grows_with_the_size_of_the_change():
    r0 = noise()
    named = [_named_over(change_of(a), r0, WEIGHTS, 1, []) for a in np.geomspace(0.01, 3, 12)]
    first = named.index(True)
    assert all(named[first:]) and not any(named[:first])


def test_an_effect_a_rival_structure_explains_as_well_is_not_named():
    r0 = noise()
    change = change_of(1.0)
    assert not _named_over(change, r0, WEIGHTS, 1, [(change, 1)])
    # A rival that explains a different shape leaves the effect named.
    other = change_of(1.0, seed=7) * np.cos(np.linspace(0.0, 9.0, HORIZON))[None, :, None]
    assert _named_over(change, r0, WEIGHTS, 1, [(other, 1)])


def test_a_rival_that_takes_only_part_of_the_change_leaves_the_rest_to_the_effect():
    r0 = noise()
    change = change_of(2.0)
    part = change_of(2.0) * np.linspace(0.0, 1.0, HORIZON)[None, :, None]
    assert _named_over(change, r0, WEIGHTS, 1, [(part, 1)])


def test_a_ladder_runs_from_the_weakest_effect_and_a_crack_pressure_from_the_highest():
    sizes = ladder((1.0, 10.0, 100.0), 'coulomb_friction', 5, below=1.0)
    assert sizes == pytest.approx((1.0, 10 ** 0.5, 10.0, 10 ** 1.5, 100.0))
    assert ladder((4.0, 100.0), 'coulomb_friction', 3)[0] == pytest.approx(1.0)
    pressures = ladder((5e6, 15e6), 'relief_valve', 3)
    assert pressures[0] == pytest.approx(15e6) and pressures[-1] == pytest.approx(5e6)


def test_the_limit_is_the_weakest_size_from_which_every_stronger_one_is_named():
    limit = DetectionLimit('coulomb_friction', 'N', (1.0, 2.0, 4.0, 8.0),
                           (True, False, True, True), 4.0, projected=4.0)
    assert not limit.below_range
    assert 'under about 4 N may go unnamed in these data' in limit.sentence()
    assert limit.to_json() == {'limit': 4.0, 'unit': 'N', 'below_range': False,
                               'sizes': [1.0, 2.0, 4.0, 8.0],
                               'named': [True, False, True, True], 'refused': None,
                               'projected': 4.0, 'stated': True}
    crack = DetectionLimit('relief_valve', 'Pa', (13e6, 11e6), (False, True), 11e6)
    assert 'above about 1.1e+07 Pa may go unnamed' in crack.sentence()
    never = DetectionLimit('transport_delay', 's', (0.001, 0.04), (False, False), None)
    assert 'not named even at 0.04 s' in never.sentence()
    always = DetectionLimit('pump_deadzone', 'rad/s', (2.0, 4.0), (True, True), 2.0)
    assert always.below_range and 'named from 2 rad/s' in always.sentence()


def test_a_size_the_record_refused_and_every_weaker_one_count_as_not_named():
    # As on the position-only draw 5010: the projection stated 0.4 ms, the record refused a
    # delay fitted at 10.9 ms.
    sizes = (0.0004, 0.0024, 0.0145, 0.04)
    stated = DetectionLimit('transport_delay', 's', sizes, (True, True, True, True), 0.0004)
    refused = refused_at(stated, 0.0109)
    assert refused.named == (False, False, True, True) and refused.limit == 0.0145
    assert refused.to_json()['refused'] == 0.0109
    assert ('under about 0.0145 s may go unnamed' in refused.sentence()
            and 'fitted here at 0.0109 s, it did no better' in refused.sentence())
    assert refused_at(refused, 0.003) == refused  # a weaker refusal changes nothing
    crack = DetectionLimit('relief_valve', 'Pa', (13e6, 11e6, 9e6), (True, True, True), 13e6)
    assert refused_at(crack, 11e6).named == (False, False, True)
    never = refused_at(stated, 0.05)
    assert never.limit is None and 'not named even at 0.04 s' in never.sentence()


def test_a_limit_is_stated_its_calibrated_margin_stronger_or_not_at_all():
    from exo_has_sim.diagnosis.limits import _limits_of, margin_of

    sizes, named = (1.0, 2.0, 4.0, 8.0, 16.0), (False, True, True, True, True)
    assert _limits_of(sizes, named, 2) == (8.0, 2.0)
    assert _limits_of(sizes, named, 0) == (2.0, 2.0)
    assert _limits_of(sizes, (False, False, False, True, True), 2) == (None, 8.0)  # past it
    assert _limits_of(sizes, named, None) == (None, 2.0)
    assert margin_of('coulomb_friction', 'rodless') == 2
    assert margin_of('transport_delay', 'either') is None  # not held on the third plant
    assert margin_of('coulomb_friction', 'mass') is None
    assert margin_of('transport_delay', 'no_pressure') is None  # not measured from position
    quiet = DetectionLimit('entrained_air', '-', sizes, named, None, projected=2.0, margin=None)
    assert not quiet.stated and 'no limit is stated' in quiet.sentence()
    assert quiet.to_json()['stated'] is False


def test_a_delay_limit_where_the_motor_lag_is_fitted_covers_the_delay_the_lag_took_up():
    # Issue 38's hold-out draw: a 12 ms delay unnamed, the lag fitted at 17.9 ms where the
    # file says 5 ms, the stated limit 1.9 ms.
    from exo_has_sim.diagnosis.fitting import Fit
    from exo_has_sim.diagnosis.limits import traded_with_lag
    from exo_has_sim.diagnosis.plants import Parameter

    # The file's +-30 % (a prior of log 1.3): the lag may be as short as 5 / 1.3 = 3.85 ms.
    lag = Parameter('motor_time_constant', 's', 0.005, 0.0005, 0.05, 'motor lag',
                    prior=math.log1p(0.3))
    fit = Fit({'motor_time_constant': 0.0179}, (lag,),
              {'motor_time_constant': (0.0165, 0.0194)})
    sizes = (0.0007, 0.0012, 0.0019, 0.0032, 0.0053, 0.0145)
    stated = DetectionLimit('transport_delay', 's', sizes, (False, True, True, True, True, True),
                            0.0019, projected=0.0007, margin=2)
    traded = traded_with_lag(stated, fit, 0.005)
    assert traded.limit == pytest.approx(0.0194 - 0.005 / 1.3) and traded.limit > 0.012
    sentence = traded.sentence()
    assert 'under about 0.0156 s may go unnamed' in sentence
    assert "trades against the motor's lag, fitted here at 0.0179 s" in sentence
    assert 'a delay up to about 0.0156 s may have been taken up by the lag' in sentence
    assert traded.to_json()['motor_lag']['delay_taken_up'] == pytest.approx(0.0156, abs=1e-4)
    # A lag fitted within its file's uncertainty took no delay; nor does a fixed one.
    low = Fit({'motor_time_constant': 0.0035}, (lag,),
              {'motor_time_constant': (0.0030, 0.0038)})
    assert traded_with_lag(stated, low, 0.005).limit == 0.0019
    assert 'trades' not in traded_with_lag(stated, low, 0.005).sentence()
    assert traded_with_lag(stated, Fit({'motor_time_constant': 0.0179}, ()), 0.005) == stated
    friction = DetectionLimit('coulomb_friction', 'N', (1.0, 2.0), (True, True), 1.0)
    assert traded_with_lag(friction, fit, 0.005) == friction
