"""A bag of our sessions reads where the workspace's message definitions are not known.

A machine with the diagnosis installed by pip, without ROS, has no share/exo_has_msgs/msg/ on
an AMENT_PREFIX_PATH: the types come from the definitions the bag embeds.
"""

import math
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from exo_has_common.bag import bag_typestore, default_typestore, read_messages
from exo_has_common.errors import BagNotFoundError

EXAMPLE_BAG = Path(__file__).resolve().parents[2] / 'bags' / 'example_diagnosis' / 'bag'


def test_a_bags_own_definitions_give_the_types_the_machine_lacks():
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    assert 'exo_has_msgs/msg/HasState' not in jazzy.fielddefs
    store = bag_typestore(EXAMPLE_BAG, jazzy)
    assert store is not jazzy and 'exo_has_msgs/msg/HasState' not in jazzy.fielddefs
    with read_messages(EXAMPLE_BAG, ['/left_hip/has_state']) as messages:
        _, msgtype, _, data = next(iter(messages))
    state = store.deserialize_cdr(data, msgtype)
    assert state.joint == 'left_hip' and 0.0 < state.position < 0.2
    assert math.isnan(state.velocity)
    # The workspace's definitions hash as the bag's do: the same types.
    assert store.hash_rihs01(msgtype) == default_typestore().hash_rihs01(msgtype)


def test_a_typestore_that_knows_every_type_of_the_bag_is_used_as_it_is():
    known = default_typestore()
    assert bag_typestore(EXAMPLE_BAG, known) is known


def test_no_bag_is_no_typestore(tmp_path):
    with pytest.raises(BagNotFoundError, match='no bag at'):
        bag_typestore(tmp_path / 'gone')
