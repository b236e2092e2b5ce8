import dataclasses
import math

import numpy as np
import pytest

from exo_has_sim.errors import ParameterError
from exo_has_sim.gait import load_gait_cycle


def test_the_shipped_winter_table_loads_in_radians():
    gait = load_gait_cycle()
    assert len(gait.cycle_percent) == 51 and gait.cycle_percent[-1] == 100.0
    assert math.degrees(gait.hip_angle.min()) == pytest.approx(-10.95)
    assert math.degrees(gait.knee_angle.max()) == pytest.approx(64.86)
    hip, _knee = gait.angles_at(np.array([0.0, 1.0, 0.5]))
    assert hip[0] == pytest.approx(hip[1])  # periodic


def test_a_user_table_of_the_same_shape_loads(tmp_path):
    path = tmp_path / 'cga.csv'
    rows = ['cycle_percent,hip_angle,knee_angle'] + [
        f'{p},{30 * math.cos(p / 100 * 2 * math.pi)},{30 + 30 * math.sin(p / 50 * math.pi)}'
        for p in range(0, 101, 5)]
    path.write_text('\n'.join(rows) + '\n')
    gait = load_gait_cycle(path)
    assert gait.hip_angle[0] == pytest.approx(math.radians(30.0))


@pytest.mark.parametrize(('text', 'message'), [
    ('a,b,c\n1,2,3\n', 'no header row with columns cycle_percent'),
    ('cycle_percent,hip_angle,knee_angle\n' + ''.join(f'{p},0.1,0.2\n' for p in range(0, 100, 10)),
     'look like radians'),
    ('cycle_percent,hip_angle,knee_angle\n' + ''.join(f'{p},10,20\n' for p in (0, 50, 40, 60, 80)),
     'must increase'),
    ('cycle_percent,hip_angle,knee_angle\n' + ''.join(f'{p},10,nan\n' for p in range(0, 100, 20)),
     'NaN'),
    ('cycle_percent,hip_angle,knee_angle\n0,1,2\n', 'fewer than 5 rows'),
])
def test_malformed_gait_tables_are_refused_with_a_clear_message(tmp_path, text, message):
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    with pytest.raises(ParameterError, match=message):
        load_gait_cycle(path)


def test_the_cycle_closes_continuously_where_100_percent_meets_0():
    gait = load_gait_cycle()
    phase = np.linspace(0.9, 1.1, 20001)
    hip, knee = gait.angles_at(phase)
    assert np.max(np.abs(np.diff(hip))) < 1e-4 and np.max(np.abs(np.diff(knee))) < 1e-4
    rate = np.diff(knee) / np.diff(phase)
    assert np.max(np.abs(np.diff(rate))) < 0.05  # no kinks: the velocity is continuous too
    np.testing.assert_allclose(gait.angles_at(gait.cycle_percent[:-1] / 100.0)[0],
                               gait.hip_angle[:-1], atol=1e-12)  # through the samples


def test_the_moments_are_the_tables_between_its_samples_and_wrap_with_the_cycle():
    gait = load_gait_cycle()
    assert gait.hip_moment is not None and gait.knee_moment is not None
    hip, knee = gait.moments_at(gait.cycle_percent[:-1] / 100.0)
    np.testing.assert_allclose(hip, gait.hip_moment[:-1])
    np.testing.assert_allclose(knee, gait.knee_moment[:-1])
    # Halfway between two samples, the mean; a phase past 1 is the next cycle's.
    middle = (gait.cycle_percent[3] + gait.cycle_percent[4]) / 200.0
    hip, _ = gait.moments_at(np.array([middle, middle + 1.0]))
    assert hip[0] == pytest.approx((gait.hip_moment[3] + gait.hip_moment[4]) / 2.0)
    assert hip[1] == pytest.approx(hip[0])
    # A table without moments gives none rather than failing.
    bare = dataclasses.replace(gait, hip_moment=None, knee_moment=None)
    assert not np.any(bare.moments_at(np.linspace(0.0, 1.0, 5))[0])
