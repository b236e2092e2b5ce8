"""The truth plants drawn around the shipped hip and knee files (issue 38: limits on them).

The plants' excitations were calibrated on the bench's 130 mm stroke (test/rigs.py); around
the shipped 40 mm cylinder they shrink by the strokes' ratio (:func:`rigs.motion_scale`), so
that every draw's motion stays within the stroke, its ends untouched, and the load keeps its
pressures.
"""

from __future__ import annotations

import numpy as np
import pytest
import second_truth_plant as plant_b
import truth_plant as plant_a
from rigs import SHIPPED_DIR, motion_scale, rig_parameters

#: The end stops' reach: a draw's position must keep at least this far from either end [m].
CLEARANCE = 0.003


@pytest.mark.parametrize('joint', ['hip', 'knee'])
@pytest.mark.parametrize(('plant', 'excitation'), [
    (plant_a, 'sine_sum'), (plant_a, 'walk'), (plant_a, 'squat'),
    (plant_b, 'sine_sum'), (plant_b, 'gait')])
def test_a_draw_around_a_shipped_file_stays_within_its_stroke(plant, excitation, joint):
    stroke = rig_parameters(joint, SHIPPED_DIR).stroke
    draw = plant.draw(3, joint, effect='none', excitation=excitation, duration=12.0,
                      rig=SHIPPED_DIR)
    position = draw.columns['position']
    assert CLEARANCE < position.min() and position.max() < stroke - CLEARANCE
    assert np.ptp(position) > 0.15 * stroke  # still an excitation
    pressure = draw.columns['pressure_a']
    assert 0.5e6 < pressure.min() and pressure.max() < 15e6  # the bench's load pressures


def test_the_bench_is_drawn_unscaled_and_the_shipped_files_by_the_strokes_ratio():
    assert motion_scale('hip') == 1.0
    assert motion_scale('knee', SHIPPED_DIR) == pytest.approx(0.04 / 0.13)
    bench = plant_a.draw(5, effect='none', duration=2.0)
    named = plant_a.draw(5, effect='none', duration=2.0, rig=None)
    assert np.array_equal(bench.columns['position'], named.columns['position'])
