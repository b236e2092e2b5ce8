import pytest

from exo_has_runtime.errors import NameValidationError
from exo_has_runtime.names import (
    RemapRule,
    expand_topic_name,
    normalize_namespace,
    remap_namespace,
    remap_node_name,
    resolve_topic_name,
    validate_node_name,
)


@pytest.mark.parametrize(('name', 'namespace', 'expected'), [
    ('chatter', '/', '/chatter'),
    ('chatter', '/exo', '/exo/chatter'),
    ('left_hip/has_command', '/exo', '/exo/left_hip/has_command'),
    ('/absolute', '/exo', '/absolute'),
    ('~/private', '/exo', '/exo/plant/private'),
    ('~', '/', '/plant'),
    ('{node}/x', '/a', '/a/plant/x'),
])
def test_topic_names_expand_as_in_rcl(name, namespace, expected):
    assert expand_topic_name(name, 'plant', namespace) == expected


@pytest.mark.parametrize('bad', ['', 'a//b', 'a/', '1abc', 'a-b', 'a/~/b', 'a b'])
def test_invalid_topic_names_are_rejected_with_the_name_in_the_message(bad):
    with pytest.raises(NameValidationError, match='invalid topic name'):
        expand_topic_name(bad, 'plant', '/')


def test_invalid_node_names_and_namespaces_are_rejected():
    with pytest.raises(NameValidationError, match="'left-hip'"):
        validate_node_name('left-hip')
    with pytest.raises(NameValidationError, match="token '9x'"):
        normalize_namespace('/exo/9x')
    assert normalize_namespace('exo/') == '/exo'
    assert normalize_namespace('') == '/'


def test_node_name_and_namespace_remaps_apply_to_their_node_only():
    rules = [RemapRule('__node', 'renamed', node='other'), RemapRule('__ns', '/exo'),
             RemapRule('__node', 'plant_left')]
    assert remap_node_name(rules, 'plant') == 'plant_left'
    assert remap_node_name(rules, 'other') == 'renamed'
    assert remap_namespace(rules, 'plant', '/') == '/exo'


def test_topic_remaps_match_after_expansion_and_respect_node_targets():
    rules = [RemapRule('cmd', 'has_command'), RemapRule('/state', '/x/state', node='talker')]
    assert resolve_topic_name(rules, 'cmd', 'n', '/exo') == '/exo/has_command'
    assert resolve_topic_name(rules, '/exo/cmd', 'n', '/exo') == '/exo/has_command'
    assert resolve_topic_name(rules, '/state', 'n', '/') == '/state'
    assert resolve_topic_name(rules, '/state', 'talker', '/') == '/x/state'
