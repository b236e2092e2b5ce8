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

import pytest
import truth_plant as tp
from diagnosis_runs import Queued, diagnose_csv

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


def twins(limits, folder):
    """Return the twins' tasks: each effect twice its stated limit, and 0.4 of its projected."""
    return [(effect, size, folder) for effect in EFFECTS
            for size in (ABOVE * limits[effect]['limit'], BELOW * limits[effect]['projected'])]


def queue_diagnoses(pool, folder):
    """Queue the effect-free draw in its pool (conftest.py), its twins on its result."""
    queued = Queued(folder)

    def queue_twins(doc):
        # On the pool's result thread, which must not raise: where a limit is missing, no
        # twins are queued, and the test fails on that limit.
        try:
            limits = doc['detection_limits']
            if all(limits[effect]['limit'] is not None for effect in EFFECTS):
                queued['twins'] = pool.map_async(diagnosed, twins(limits, folder), chunksize=1)
        except (KeyError, TypeError):
            pass

    queued['none'] = pool.apply_async(diagnosed, (('none', None, folder),),
                                      callback=queue_twins)
    return queued


def test_an_effect_twice_the_stated_limit_is_named_and_one_under_half_of_it_is_not(diagnoses):
    queued = diagnoses
    limits = queued['none'].get()['detection_limits']
    assert not limits[UNSTATED]['stated'] and limits[UNSTATED]['limit'] is None
    for effect in EFFECTS:
        limit = limits[effect]
        assert limit['limit'] is not None and limit['limit'] > limit['projected'], (effect,
                                                                                    limit)
    tasks = twins(limits, queued.folder)
    docs = queued['twins'].get()
    for (effect, size, _), doc in zip(tasks, docs, strict=True):
        above = size > limits[effect]['limit']
        assert (doc['causes'][:1] == [effect]) == above, (effect, size, doc['causes'])
