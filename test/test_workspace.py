"""The workspace is a valid ROS 2 workspace: manifests, build types, messages, executables."""

import ast
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from catkin_pkg.package import parse_package

WORKSPACE = Path(__file__).resolve().parents[1]
PACKAGES = {
    'exo_has_msgs': 'ament_cmake',
    'exo_has_common': 'ament_python',
    'exo_has_runtime': 'ament_python',
    'exo_has_sim': 'ament_python',
    'exo_has_control': 'ament_python',
    'exo_has_driver': 'ament_python',
    'exo_has_bringup': 'ament_python',
}


@pytest.mark.parametrize(('name', 'build_type'), sorted(PACKAGES.items()))
def test_every_package_xml_is_a_valid_format_3_manifest(name, build_type):
    package = parse_package(str(WORKSPACE / name / 'package.xml'))
    package.validate()
    assert package.name == name and package.package_format == 3
    assert package.get_build_type() == build_type
    if build_type == 'ament_python':
        assert (WORKSPACE / name / 'resource' / name).is_file()
        assert (WORKSPACE / name / 'setup.cfg').read_text().count(f'$base/lib/{name}') == 2
        assert 'exo_has_common' in {d.name for d in package.exec_depends} \
            or name == 'exo_has_common'


def test_the_message_package_is_an_interface_package():
    package = parse_package(str(WORKSPACE / 'exo_has_msgs' / 'package.xml'))
    assert 'rosidl_interface_packages' in [g.name for g in package.member_of_groups]
    cmake = (WORKSPACE / 'exo_has_msgs' / 'CMakeLists.txt').read_text()
    for msg_file in sorted((WORKSPACE / 'exo_has_msgs' / 'msg').glob('*.msg')):
        assert f'"msg/{msg_file.name}"' in cmake


@pytest.mark.process
def test_colcon_lists_the_packages_with_their_build_types():
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent))
    if colcon is None:
        pytest.skip('colcon is not installed (requirements-dev.txt installs colcon-core)')
    listing = subprocess.run(
        [colcon, 'list', '--base-paths', str(WORKSPACE)], capture_output=True, text=True,
        check=True, cwd=WORKSPACE).stdout
    found = {line.split('\t')[0]: line.split('\t')[2].strip('()')
             for line in listing.splitlines() if line}
    assert found == {name: f'ros.{build_type}' for name, build_type in PACKAGES.items()}


def test_every_field_of_every_message_is_documented():
    for msg_file in sorted((WORKSPACE / 'exo_has_msgs' / 'msg').glob('*.msg')):
        lines = msg_file.read_text().splitlines()
        for number, line in enumerate(lines):
            if line and not line.startswith('#') and '=' not in line:
                assert lines[number - 1].startswith('#'), f'{msg_file.name}: {line!r}'


def console_scripts(package):
    """Return the console_scripts names declared in a package's setup.py."""
    tree = ast.parse((WORKSPACE / package / 'setup.py').read_text(encoding='utf-8'))
    (call,) = [node for node in ast.walk(tree)
               if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'setup']
    (entry_points,) = [k.value for k in call.keywords if k.arg == 'entry_points']
    scripts = ast.literal_eval(entry_points).get('console_scripts', [])
    return [script.split('=')[0].strip() for script in scripts]


#: The packages with executables (nodes, exo-has); exo_has_common and exo_has_bringup have none:
#: bringup's demo is an exo-has subcommand.
WITH_EXECUTABLES = ('exo_has_runtime', 'exo_has_sim', 'exo_has_control', 'exo_has_driver',
                    'exo_has_bringup')


def test_only_the_packages_with_executables_declare_console_scripts():
    assert {n for n, b in PACKAGES.items() if b == 'ament_python' and console_scripts(n)} \
        == set(WITH_EXECUTABLES)


@pytest.mark.parametrize('package', WITH_EXECUTABLES)
def test_every_console_script_is_installed_where_ros2_run_looks(package):
    names = console_scripts(package)
    assert names
    installed = Path(get_package_prefix(package)) / 'lib' / package
    for name in names:
        executable = installed / name
        assert executable.is_file() and os.access(executable, os.X_OK), executable


@pytest.mark.process
def test_the_installed_plant_executable_starts_publishes_and_stops_cleanly(ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from exo_has_msgs.msg import HasState
    from exo_has_runtime.processes import tethered

    plant = Path(get_package_prefix('exo_has_sim')) / 'lib' / 'exo_has_sim' / 'plant'
    node = Node('workspace_listener', context=ros_context)
    states = []
    node.create_subscription(HasState, 'left_knee/has_state', states.append,
                             qos_profile_sensor_data)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    with tempfile.TemporaryFile() as log:
        process = subprocess.Popen(tethered([str(plant), '--ros-args', '-p', 'joint:=left_knee']),
                                   stdout=log, stderr=subprocess.STDOUT,
                                   cwd=tempfile.gettempdir())
        try:
            # Generous: the first start compiles the model.
            deadline = time.monotonic() + 60.0
            while not states and time.monotonic() < deadline and process.poll() is None:
                executor.spin_once(timeout_sec=0.1)
        finally:
            process.send_signal(signal.SIGINT)
            try:
                code = process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                code = process.wait()
            executor.shutdown()
            node.destroy_node()
        log.seek(0)
        output = log.read().decode('utf-8', errors='replace')
    assert states, f'no HasState from {plant}; its output:\n{output}'
    assert states[0].joint == 'left_knee'
    assert code == 0, output
    assert 'left_knee plant ready' in output


@pytest.mark.process
def test_the_controller_watchdog_and_driver_start_without_loading_the_simulator():
    # They read joint names (exo_has_common.joints) and the PD law (exo_has_sim.control_law),
    # not the numba-compiled model: loading it would cost each node seconds and rewrite caches.
    code = ('import sys; import exo_has_control.pd_controller, exo_has_driver.watchdog, '
            'exo_has_driver.driver_node; '
            "print(sorted(m for m in sys.modules if m == 'numba' or m in "
            "('exo_has_sim.model', 'exo_has_sim.simulate', 'exo_has_sim.plant')))")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=60, check=True)
    assert result.stdout.strip() == '[]', result.stdout + result.stderr
