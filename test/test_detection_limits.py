"""A record's own detection limits (exo_has_sim.diagnosis.limits) against full diagnoses of it.

One effect-free draw of the first truth plant is diagnosed; its JSON gives, for each effect,
the size from which this record would name it: the limit stated, a calibrated margin stronger
than the one projected (exo_has_sim.diagnosis.limits.LIMIT_MARGIN), or none where no margin
held on the truth plants. The draw's twins with an effect (the same seed: the same nuisance
parameters, excitation, load and noise, :func:`truth_plant.draw`) are then diagnosed in full,
as a user would: at twice the stated limit the effect must be named, at 0.4 of the projected
one not. That is the claim the report makes, checked on data our model did not make.
"""

from __future__ import annotations

import multiprocessing
import os

import pytest
import truth_plant as tp
from diagnosis_runs import diagnose_csv

pytestmark = pytest.mark.slow  # every test here runs long diagnoses

SEED = 70000
EFFECTS = ('coulomb_friction', 'pump_deadzone')
#: No limit is stated for it: on the second truth plant it was named in 75 % of records four
#: ladder steps above the projected limit.
UNSTATED = 'quadratic_leakage'
ABOVE, BELOW = 2.0, 0.4


def diagnosed(task):
    """Draw a twin of the seed, write it as CSV, diagnose it; the JSON document."""
    effect, size, folder = task
    draw = tp.draw(SEED, effect=effect, size=size, duration=30.0)
    path = folder / f'{effect}_{size}.csv'
    tp.write_csv(draw, path)
    return diagnose_csv(path, draw.joint_type, draw.load_mass, path.with_suffix('.json'))


def test_an_effect_twice_the_stated_limit_is_named_and_one_under_half_of_it_is_not(tmp_path):
    limits = diagnosed(('none', None, tmp_path))['detection_limits']
    assert not limits[UNSTATED]['stated'] and limits[UNSTATED]['limit'] is None
    tasks = []
    for effect in EFFECTS:
        limit = limits[effect]
        assert limit['limit'] is not None and limit['limit'] > limit['projected'], (effect,
                                                                                    limit)
        tasks += [(effect, ABOVE * limit['limit'], tmp_path),
                  (effect, BELOW * limit['projected'], tmp_path)]
    with multiprocessing.get_context('spawn').Pool(os.cpu_count() or 1) as pool:
        docs = pool.map(diagnosed, tasks, chunksize=1)
    for (effect, size, _), doc in zip(tasks, docs, strict=True):
        above = size > limits[effect]['limit']
        assert (doc['causes'][:1] == [effect]) == above, (effect, size, doc['causes'])
