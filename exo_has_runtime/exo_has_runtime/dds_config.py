"""``exo-has dds-config``: print the Cyclone DDS configuration standalone nodes use by default.

On a ROS 2 machine, ``export CYCLONEDDS_URI="$(ros2 run exo_has_runtime exo-has dds-config)"``
before ``ros2 run`` gives rmw_cyclonedds_cpp nodes the same loopback-only discovery, so they
and standalone nodes on that machine find each other without multicast.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

# The text lives here, not in the standalone backend, so that printing it needs no DDS binding.
LOOPBACK_CONFIG = (
    '<CycloneDDS><Domain id="any"><General>'
    '<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    '<AllowMulticast>false</AllowMulticast></General>'
    '<Discovery><ParticipantIndex>auto</ParticipantIndex>'
    '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>'
    '<Peers><Peer address="localhost"/></Peers></Discovery></Domain></CycloneDDS>'
)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the configuration."""
    parser = argparse.ArgumentParser(prog='exo-has dds-config',
                                     description=__doc__.splitlines()[0])
    parser.parse_args(argv)
    print(LOOPBACK_CONFIG)
    return 0
