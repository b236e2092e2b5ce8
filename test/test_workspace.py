"""The workspace is a valid ROS 2 workspace: manifests, build types, message definitions."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package

from exo_has_runtime.standalone.messages import default_registry

WORKSPACE = Path(__file__).resolve().parents[1]
PACKAGES = {
    'exo_has_msgs': 'ament_cmake',
    'exo_has_runtime': 'ament_python',
    'exo_has_sim': 'ament_python',
    'exo_has_control': 'ament_python',
    'exo_has_driver': 'ament_python',
}
SYSTEM_PYTHON = '/usr/bin/python3'


@pytest.mark.parametrize(('name', 'build_type'), sorted(PACKAGES.items()))
def test_every_package_xml_is_a_valid_format_3_manifest(name, build_type):
    package = parse_package(str(WORKSPACE / name / 'package.xml'))
    package.validate()
    assert package.name == name and package.package_format == 3
    assert package.get_build_type() == build_type
    if build_type == 'ament_python':
        assert (WORKSPACE / name / 'resource' / name).is_file()
        assert (WORKSPACE / name / 'setup.cfg').read_text().count(f'$base/lib/{name}') == 2
        assert 'exo_has_runtime' in {d.name for d in package.exec_depends} \
            or name == 'exo_has_runtime'


def test_the_message_package_is_an_interface_package():
    package = parse_package(str(WORKSPACE / 'exo_has_msgs' / 'package.xml'))
    assert 'rosidl_interface_packages' in [g.name for g in package.member_of_groups]
    cmake = (WORKSPACE / 'exo_has_msgs' / 'CMakeLists.txt').read_text()
    for msg_file in sorted((WORKSPACE / 'exo_has_msgs' / 'msg').glob('*.msg')):
        assert f'"msg/{msg_file.name}"' in cmake


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


def _rosidl_available():
    try:
        return subprocess.run([SYSTEM_PYTHON, '-c', 'import rosidl_adapter.parser'],
                              capture_output=True, check=False).returncode == 0
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not _rosidl_available(),
                    reason="the official rosidl parser (Debian's python3-rosidl) is not installed")
def test_the_official_rosidl_parser_reads_our_msg_files_as_we_do():
    script = (
        'import json, sys\n'
        'from rosidl_adapter.parser import parse_message_file\n'
        'out = {}\n'
        'for path in sys.argv[1:]:\n'
        '    spec = parse_message_file("exo_has_msgs", path)\n'
        '    out[spec.base_type.type] = {\n'
        '        "fields": [[f.name, str(f.type)] for f in spec.fields],\n'
        '        "constants": [[c.name, c.value] for c in spec.constants]}\n'
        'print(json.dumps(out))\n')
    files = sorted(str(p) for p in (WORKSPACE / 'exo_has_msgs' / 'msg').glob('*.msg'))
    import json
    parsed = json.loads(subprocess.run([SYSTEM_PYTHON, '-c', script, *files],
                                       capture_output=True, text=True, check=True).stdout)
    registry = default_registry()
    assert sorted(parsed) == ['HasCommand', 'HasState', 'SafetyEvent']
    for name, spec in parsed.items():
        message_type = registry.get_message(f'exo_has_msgs/msg/{name}')
        ours = message_type.get_fields_and_field_types()
        assert [field for field, _ in spec['fields']] == list(ours)
        for field, rosidl_type in spec['fields']:
            assert rosidl_type.replace('/', '/') == ours[field] or \
                rosidl_type == ours[field].replace('/msg/', '/')
        for constant, value in spec['constants']:
            assert getattr(message_type, constant) == value


def test_every_field_of_every_message_is_documented():
    for msg_file in sorted((WORKSPACE / 'exo_has_msgs' / 'msg').glob('*.msg')):
        lines = msg_file.read_text().splitlines()
        for number, line in enumerate(lines):
            if line and not line.startswith('#') and '=' not in line:
                assert lines[number - 1].startswith('#'), f'{msg_file.name}: {line!r}'
