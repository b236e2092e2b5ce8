"""The controller's rejoin speed against the gait and the watchdog's start-up grace.

The controller joins a reference at :data:`~exo_has_control.tracking.DEFAULT_REJOIN_SPEED`;
the watchdog judges tracking from :data:`~exo_has_driver.safety_limits.DEFAULT_STARTUP_GRACE`
on. The two packages never import each other; this test holds their defaults together.
"""

import numpy as np
import pytest

from exo_has_common.joints import JOINT_NAMES
from exo_has_control.tracking import DEFAULT_REJOIN_SPEED
from exo_has_control.trajectory import Schedule, TrialPlan
from exo_has_driver.safety_limits import DEFAULT_STARTUP_GRACE
from exo_has_sim.gait import WINTER, load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters

KNEE = load_parameters('knee')
PERIOD = 0.005  # s


def test_the_default_rejoin_speed_is_slow_beside_the_gait_and_crosses_a_stroke_in_the_grace():
    gait = load_gait_cycle(WINTER)
    t = np.arange(0.0, 10.0, PERIOD)
    peaks = {}
    for motion in ('walk', 'squat'):
        angles, rates = (np.asarray(a) for a in Schedule((TrialPlan(motion, 10.0),))
                         .references(gait, t))
        for index, joint in enumerate(JOINT_NAMES[:2]):  # left hip and knee: both sides alike
            params = load_parameters('hip' if joint.endswith('hip') else 'knee')
            linkage = Linkage.from_parameters(params)
            speeds = [abs(linkage.velocity_at(a, r))
                      for a, r in zip(angles[:, index], rates[:, index], strict=True)]
            peaks[motion, joint] = max(speeds)
    # The figures tracking.DEFAULT_REJOIN_SPEED's comment gives.
    assert peaks['walk', 'left_knee'] == pytest.approx(0.16, abs=0.01)
    assert DEFAULT_REJOIN_SPEED <= peaks['walk', 'left_knee'] / 6
    assert all(DEFAULT_REJOIN_SPEED <= peaks['squat', j] / 2.8 for j in JOINT_NAMES[:2])
    assert KNEE.stroke / DEFAULT_REJOIN_SPEED < min(3.0, DEFAULT_STARTUP_GRACE)
