"""The ``plant`` command: the plant node in a ROS 2 workspace, a one-line refusal elsewhere.

pip installs exo_has_sim where no ROS is, for the diagnosis (docs/diagnosing-many.md), and the
command with it; the node needs rclpy, the project's messages and exo_has_runtime, which only
a ROS 2 workspace has. There the command says so and names what this installation can do,
where a bare import would end in a traceback.
"""

from __future__ import annotations

import sys


def main(args: list[str] | None = None) -> int:
    """Run the plant node (:mod:`exo_has_sim.plant_node`); return 2 where ROS 2 is missing."""
    try:
        # Imported here, not above: the refusal must not need what it refuses for.
        from exo_has_sim.plant_node import main as run_plant
    except ModuleNotFoundError as exc:
        print(f'plant: the plant node needs ROS 2 Jazzy, and {exc.name} is not installed here; '
              'run it in a workspace (ros2 run exo_has_sim plant). Without ROS this '
              'installation diagnoses records: exo-has-diagnose --help', file=sys.stderr)
        return 2
    run_plant(args)
    return 0


if __name__ == '__main__':
    sys.exit(main())
