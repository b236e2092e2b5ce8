r"""Several nodes in one process, as ROS 2 composition does, without a component manager.

Each node is named by its class (``package.module:Class``) and followed by its own ROS
arguments, which apply to it alone (a node remap, ``-p`` parameters, a params file), the way a
component container hands each component its ``NodeOptions`` arguments::

    ros2 run exo_has_runtime container \\
        --node exo_has_sim.plant_node:PlantNode --ros-args -r __node:=left_hip_plant \\
            -p joint:=left_hip \\
        --node exo_has_sim.plant_node:PlantNode --ros-args -r __node:=right_hip_plant \\
            -p joint:=right_hip

ROS arguments before the first ``--node`` are global: every node sees them (``use_sim_time``,
a log level). The nodes share one context, so one DDS participant, and one executor thread
(:func:`exo_has_runtime.execution.run_nodes`): their callbacks never run at the same time,
and one process's fixed costs (interpreter, DDS threads) are paid once.
A node class takes Node's keyword arguments (``cli_args``, ``context``) for this.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

from rclpy.node import Node

from exo_has_runtime.errors import ContainerArgumentError
from exo_has_runtime.execution import run_nodes

#: Marks the start of one node's class and arguments on the command line.
NODE_FLAG = '--node'


@dataclass(frozen=True)
class ComponentSpec:
    """One node of a container: its class, as ``package.module:Class``, and its ROS arguments."""

    target: str
    arguments: tuple[str, ...] = ()

    def command_line(self) -> list[str]:
        """Return this node's part of the container's command line."""
        return [NODE_FLAG, self.target, *self.arguments]


def split_arguments(argv: Sequence[str]) -> tuple[list[str], list[ComponentSpec]]:
    """Split a container's command line into global ROS arguments and one spec per node.

    Raises
    ------
    ContainerArgumentError
        If no node is named or a ``--node`` has no class after it.

    """
    global_arguments: list[str] = []
    specs: list[ComponentSpec] = []
    current: list[str] | None = None
    target = ''
    for token in argv:
        if token == NODE_FLAG:
            if current is not None:
                specs.append(ComponentSpec(target, tuple(current)))
            current, target = [], ''
        elif current is None:
            global_arguments.append(token)
        elif not target:
            if token.startswith('-'):
                msg = f'{NODE_FLAG} must be followed by package.module:Class, not {token!r}'
                raise ContainerArgumentError(msg)
            target = token
        else:
            current.append(token)
    if current is not None:
        if not target:
            msg = f'{NODE_FLAG} at the end of the command line names no node class'
            raise ContainerArgumentError(msg)
        specs.append(ComponentSpec(target, tuple(current)))
    if not specs:
        msg = f'no node to run: give {NODE_FLAG} package.module:Class [--ros-args ...] per node'
        raise ContainerArgumentError(msg)
    return global_arguments, specs


def node_class(target: str) -> type[Node]:
    """Import the node class a ``package.module:Class`` names.

    Raises
    ------
    ContainerArgumentError
        If the module or the class does not exist, or the class is not an rclpy Node.

    """
    module_name, _, class_name = target.partition(':')
    if not module_name or not class_name:
        msg = f'node class {target!r}: expected package.module:Class'
        raise ContainerArgumentError(msg)
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        msg = f'node class {target!r}: cannot import {module_name}: {exc}'
        raise ContainerArgumentError(msg) from None
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        msg = f'node class {target!r}: {module_name} has no rclpy Node class {class_name}'
        raise ContainerArgumentError(msg)
    return cls


def factories(specs: Sequence[ComponentSpec]) -> list[Callable[[], Node]]:
    """One factory per node, each building its class with its own ROS arguments."""
    return [partial(node_class(spec.target), cli_args=list(spec.arguments)) for spec in specs]


def main(args: Sequence[str] | None = None) -> None:
    """Run the nodes the command line names in one process until interrupted."""
    argv = list(sys.argv if args is None else args)
    try:
        global_arguments, specs = split_arguments(argv[1:])
        node_factories = factories(specs)
    except ContainerArgumentError as exc:
        print(f'[FATAL] [container]: {exc}', file=sys.stderr)
        raise SystemExit(2) from None
    run_nodes(node_factories, [argv[0], *global_arguments], name='container')


if __name__ == '__main__':
    main()
