"""The package graph of the architecture section (docs/developing.md) holds in the code.

Imports go one way, down the layers: exo_has_common (free of rclpy) <- exo_has_runtime (the
rclpy seams) <- exo_has_sim <- exo_has_control and exo_has_driver <- exo_has_bringup. The
physics (every module of exo_has_sim but its ROS-facing ones) imports nothing of ROS nor any
package that does; so do the ROS-free cores of the controller and the driver. The code is read
with :mod:`ast` (nothing is imported); imports inside functions count as well.
"""

import ast
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path

import pytest

WORKSPACE = Path(__file__).resolve().parents[1]

#: Each package and the exo_has packages it may import (besides itself).
ALLOWED = {
    'exo_has_common': set(),
    'exo_has_runtime': {'exo_has_common', 'exo_has_msgs'},
    'exo_has_sim': {'exo_has_common', 'exo_has_runtime', 'exo_has_msgs'},
    'exo_has_control': {'exo_has_common', 'exo_has_runtime', 'exo_has_sim', 'exo_has_msgs'},
    'exo_has_driver': {'exo_has_common', 'exo_has_runtime', 'exo_has_sim', 'exo_has_msgs'},
    'exo_has_bringup': {'exo_has_common', 'exo_has_runtime', 'exo_has_sim', 'exo_has_control',
                        'exo_has_driver', 'exo_has_msgs'},
}

#: What a module free of ROS may not import: rclpy, message packages, and the packages built on
#: them.
ROS = ('rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs',
       'builtin_interfaces', 'exo_has_msgs', 'exo_has_runtime', 'exo_has_control',
       'exo_has_driver', 'exo_has_bringup')

#: The modules of the ROS-free packages' layers that face ROS: nodes and message conversions.
ROS_FACING = {
    # plant_command imports the node only when run, and refuses in a line where ROS is not.
    'exo_has_sim': {'exo_has_sim.plant_node', 'exo_has_sim.plant_command',
                    'exo_has_sim.state_message'},
    'exo_has_control': {'exo_has_control.pd_controller', 'exo_has_control.gait_publisher',
                        'exo_has_control.gain_parameters'},
    'exo_has_driver': {'exo_has_driver.watchdog', 'exo_has_driver.driver_node',
                       'exo_has_driver.messages'},
}


def module_name(path: Path) -> str:
    """Return the dotted name of a product module from its path."""
    parts = list(path.relative_to(WORKSPACE).with_suffix('').parts[1:])
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


@cache
def product_modules() -> dict[str, Path]:
    """Return every product module of the workspace's Python packages, by dotted name."""
    return {module_name(path): path for package in ALLOWED
            for path in sorted((WORKSPACE / package / package).rglob('*.py'))}


@cache
def imports_of(module: str) -> frozenset[str]:
    """Return the absolute names a module imports, anywhere in its code."""
    path = product_modules()[module]
    package = module if path.name == '__init__.py' else module.rpartition('.')[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')[:len(package.split('.')) - node.level + 1]
                stem = '.'.join([*base, node.module] if node.module else base)
            else:
                stem = node.module or ''
            names.add(stem)
            # `from package import module` imports the module.
            names.update(f'{stem}.{alias.name}' for alias in node.names
                         if f'{stem}.{alias.name}' in product_modules())
    return frozenset(names)


def top(name: str) -> str:
    return name.partition('.')[0]


def test_every_package_imports_only_the_packages_below_it():
    wrong = [f'{module} imports {name}' for module in product_modules()
             for name in sorted(imports_of(module))
             if top(name).startswith('exo_has_') and top(name) != top(module)
             and top(name) not in ALLOWED[top(module)]]
    assert not wrong, '\n'.join(wrong)


@pytest.mark.parametrize('package', ['exo_has_common', 'exo_has_sim', 'exo_has_control',
                                     'exo_has_driver'])
def test_the_ros_free_modules_import_nothing_of_ros(package):
    facing = ROS_FACING.get(package, set())
    wrong = [f'{module} imports {name}' for module in product_modules()
             if top(module) == package and module not in facing
             for name in sorted(imports_of(module))
             if (top(name) in ROS and top(name) != package) or name in facing]
    assert not wrong, '\n'.join(wrong)


def test_every_module_named_ros_facing_exists_and_faces_ros():
    # A stale entry would let a new module of that name slip past the rule above.
    for package, modules in ROS_FACING.items():
        for module in modules:
            assert module in product_modules(), f'{module} (ROS_FACING) does not exist'
            assert any(top(name) in ROS or (name in modules and name != module)
                       for name in imports_of(module)), \
                f'{module} imports nothing of ROS: it belongs to the ROS-free part of {package}'


def test_every_package_xml_depends_only_on_the_packages_below_it():
    # colcon orders the build by these, test dependencies included: one upward is a cycle.
    wrong = []
    for package, allowed in ALLOWED.items():
        manifest = ET.parse(WORKSPACE / package / 'package.xml').getroot()
        wrong += [f'{package}: <{tag.tag}>{tag.text}</{tag.tag}>' for tag in manifest
                  if tag.tag.endswith('depend') and (tag.text or '').startswith('exo_has_')
                  and tag.text not in allowed]
    assert not wrong, '\n'.join(wrong)


def test_no_product_module_imports_a_test_helper_or_a_module_named_testing():
    wrong = [f'{module} imports {name}' for module in product_modules()
             for name in imports_of(module)
             if 'testing' in name.split('.') or top(name) in ('pytest', 'conftest')]
    assert not wrong, '\n'.join(wrong)


def test_the_modules_import_one_another_without_cycles():
    graph = {module: {name for name in imports_of(module) if name in product_modules()
                      and name != module and not module.startswith(f'{name}.')}
             for module in product_modules()}
    state: dict[str, int] = {}
    cycles = []

    def visit(module, path):
        state[module] = 1
        for name in sorted(graph[module]):
            if state.get(name) == 1:
                cycles.append(' -> '.join([*path[path.index(name):], name]))
            elif name not in state:
                visit(name, [*path, name])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, '\n'.join(cycles)


def test_no_product_file_is_longer_than_600_lines():
    long = [f'{path.relative_to(WORKSPACE)}: {count} lines'
            for path in product_modules().values()
            if (count := len(path.read_text().splitlines())) > 600]
    assert not long, '\n'.join(long)


def test_no_two_product_classes_share_a_name():
    # One name, one thing: a reader who meets Watchdog or Plant knows which is meant.
    where: dict[str, list[str]] = {}
    for module, path in product_modules().items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(module)
    shared = {name: modules for name, modules in where.items() if len(modules) > 1}
    assert not shared, shared
