import pytest

from exo_has_runtime.arguments import (
    load_params_file,
    node_pattern_matches,
    parameter_overrides_for,
    parse_ros_args,
)
from exo_has_runtime.errors import CommandLineError
from exo_has_runtime.names import RemapRule


def test_ros_args_sections_are_parsed_and_other_arguments_kept():
    args = parse_ros_args([
        'prog', 'positional', '--ros-args', '-p', 'gain:=35.0', '--param', 'on:=true',
        '-r', '__ns:=/exo', '--remap', 'talker:cmd:=has_command', '--log-level', 'debug',
        '--', 'tail', '--ros-args', '-p', 'names:=[a, b]'])
    assert args.non_ros_args == ['prog', 'positional', 'tail']
    assert [(o.name, o.value) for o in args.parameter_overrides] == [
        ('gain', 35.0), ('on', True), ('names', ['a', 'b'])]
    assert args.remap_rules == [RemapRule('__ns', '/exo'),
                                RemapRule('cmd', 'has_command', node='talker')]
    assert args.log_levels == {'': 'debug'}


@pytest.mark.parametrize(('argv', 'message'), [
    (['p', '--ros-args', '--bogus'], "unknown ROS argument '--bogus'"),
    (['p', '--ros-args', '-p'], 'needs a value'),
    (['p', '--ros-args', '-p', 'novalue'], 'expected name:=value'),
    (['p', '--ros-args', '-r', 'a:b'], r'expected \[node:\]from:=to'),
    (['p', '--ros-args', '-p', 'mixed:=[1, 2.0]'], "'mixed'.*mixes integers and floats"),
    (['p', '--ros-args', '-p', 'empty:=[]'], "'empty'.*empty list"),
    (['p', '--ros-args', '--log-level', 'loud'], 'level must be one of'),
])
def test_malformed_ros_arguments_fail_with_a_message_naming_the_problem(argv, message):
    with pytest.raises(CommandLineError, match=message):
        parse_ros_args(argv)


def test_params_files_in_the_ros2_format_are_flattened_per_node(tmp_path):
    path = tmp_path / 'params.yaml'
    path.write_text(
        '/**:\n  ros__parameters:\n    rate: 200.0\n'
        'exo:\n  left_hip_plant:\n    ros__parameters:\n'
        '      model:\n        bulk_modulus: 1.0e9\n'
        '/exo/left_hip_plant:\n  ros__parameters:\n    rate: 1000.0\n')
    overrides = load_params_file(path)
    assert [(o.node_pattern, o.name, o.value) for o in overrides] == [
        ('/**', 'rate', 200.0), ('/exo/left_hip_plant', 'model.bulk_modulus', 1.0e9),
        ('/exo/left_hip_plant', 'rate', 1000.0)]
    chosen = parameter_overrides_for(overrides, '/exo/left_hip_plant')
    assert chosen['rate'].value == 1000.0
    assert parameter_overrides_for(overrides, '/other')['rate'].value == 200.0


def test_a_node_specific_value_wins_over_a_wildcard_given_later():
    path_args = parse_ros_args(['p', '--ros-args', '-p', 'rate:=5.0'])
    overrides = [*path_args.parameter_overrides]
    overrides.insert(0, overrides[0].__class__('/plant', 'rate', 7.0, 'file'))
    assert parameter_overrides_for(overrides, '/plant')['rate'].value == 7.0


@pytest.mark.parametrize(('pattern', 'name', 'expected'), [
    ('/**', '/a/b/c', True), ('/**', '/c', True), ('c', '/c', True), ('/c', '/a/c', False),
    ('/*/c', '/a/c', True), ('/*/c', '/c', False), ('/**/c', '/a/b/c', True),
    ('/a/**', '/a/b/c', True), ('/a/**', '/b/c', False),
])
def test_node_patterns_follow_the_rcl_wildcards(pattern, name, expected):
    assert node_pattern_matches(pattern, name) is expected


@pytest.mark.parametrize(('text', 'message'), [
    ('a: [unclosed', 'not valid YAML'),
    ('- 1\n- 2\n', 'expected a mapping'),
    ('node:\n  gain: 1\n', r'outside any "ros__parameters"'),
    ('node:\n  ros__parameters:\n    bad: null\n', "'bad'.*null"),
    ('node:\n  ros__parameters: 3\n', 'is not a mapping'),
])
def test_malformed_params_files_name_the_file_and_the_problem(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CommandLineError, match=message) as raised:
        load_params_file(path)
    assert 'bad.yaml' in str(raised.value)


def test_a_missing_params_file_is_reported(tmp_path):
    with pytest.raises(CommandLineError, match=r'cannot read parameters file .*missing\.yaml'):
        parse_ros_args(['p', '--ros-args', '--params-file', str(tmp_path / 'missing.yaml')])
