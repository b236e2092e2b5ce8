"""ROS 2 names: validation, expansion and remapping (REP 144 and the rcl rules).

Pure functions, free of any middleware.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from exo_has_runtime.errors import NameValidationError

_NODE_NAME = re.compile(r'[A-Za-z_][A-Za-z0-9_]*\Z')
_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*\Z')
_TOPIC_CHARS = re.compile(r'[A-Za-z0-9_/~{}]*\Z')


def validate_node_name(name: str) -> str:
    """Return ``name`` if it is a valid ROS 2 node name.

    Parameters
    ----------
    name : str
        Candidate node name.

    Returns
    -------
    str
        The same name.

    Raises
    ------
    NameValidationError
        If the name is empty or has characters other than letters, digits and underscores, or
        starts with a digit.

    """
    if not _NODE_NAME.match(name):
        msg = (
            f'invalid node name {name!r}: a node name is letters, digits and underscores, '
            'not starting with a digit'
        )
        raise NameValidationError(msg)
    return name


def normalize_namespace(namespace: str) -> str:
    """Return a validated absolute namespace ('' and '/' both mean the root).

    Parameters
    ----------
    namespace : str
        Namespace, absolute or relative (a relative one is taken from the root, as rcl does).

    Returns
    -------
    str
        The namespace with one leading slash and no trailing slash ('/' for the root).

    Raises
    ------
    NameValidationError
        If a token of the namespace is not a valid name token.

    """
    tokens = [token for token in namespace.strip('/').split('/') if token]
    for token in tokens:
        if not _TOKEN.match(token):
            msg = (
                f'invalid namespace {namespace!r}: token {token!r} must be letters, digits and '
                'underscores, not starting with a digit'
            )
            raise NameValidationError(msg)
    if '//' in namespace.strip('/'):
        msg = f'invalid namespace {namespace!r}: repeated slash'
        raise NameValidationError(msg)
    return '/' + '/'.join(tokens)


def expand_topic_name(name: str, node_name: str, namespace: str) -> str:
    """Expand a topic name to its fully qualified form.

    Parameters
    ----------
    name : str
        Topic name: absolute (``/a/b``), relative (``a/b``, taken from the node's namespace) or
        private (``~/a``, taken from the node's fully qualified name). ``{node}`` and ``{ns}``
        substitutions are expanded.
    node_name : str
        Name of the node that uses the topic.
    namespace : str
        Absolute namespace of that node.

    Returns
    -------
    str
        Fully qualified topic name, starting with a slash.

    Raises
    ------
    NameValidationError
        If the name is empty, has characters ROS 2 forbids, a repeated or trailing slash, or a
        token that starts with a digit.

    """
    if not name:
        raise NameValidationError('invalid topic name: empty')
    if not _TOPIC_CHARS.match(name):
        msg = f'invalid topic name {name!r}: only letters, digits, underscores and slashes'
        raise NameValidationError(msg)
    ns = normalize_namespace(namespace)
    expanded = name.replace('{node}', node_name).replace('{ns}', ns.strip('/'))
    if expanded == '~' or expanded.startswith('~/'):
        base = ns.rstrip('/') + '/' + node_name
        expanded = base + expanded[1:]
    elif '~' in expanded:
        msg = f'invalid topic name {name!r}: "~" may only start a name'
        raise NameValidationError(msg)
    elif not expanded.startswith('/'):
        expanded = ns.rstrip('/') + '/' + expanded
    if expanded.endswith('/') or '//' in expanded:
        msg = f'invalid topic name {name!r}: repeated or trailing slash'
        raise NameValidationError(msg)
    for token in expanded.strip('/').split('/'):
        if not _TOKEN.match(token):
            msg = f'invalid topic name {name!r}: token {token!r} must not start with a digit'
            raise NameValidationError(msg)
    return expanded


@dataclass(frozen=True)
class RemapRule:
    """One ``-r [node:]from:=to`` rule of the ROS command line.

    Attributes
    ----------
    source : str
        Name to match (``__ns``, ``__node`` or a topic name).
    target : str
        Replacement.
    node : str or None
        Name of the only node the rule applies to; None for every node.

    """

    source: str
    target: str
    node: str | None = None

    def applies_to(self, node_name: str) -> bool:
        """Tell whether the rule applies to a node of this (original) name."""
        return self.node is None or self.node == node_name


def remap_node_name(rules: Sequence[RemapRule], node_name: str) -> str:
    """Apply the first matching ``__node:=`` rule to a node name."""
    for rule in rules:
        if rule.source == '__node' and rule.applies_to(node_name):
            return validate_node_name(rule.target)
    return node_name


def remap_namespace(rules: Sequence[RemapRule], node_name: str, namespace: str) -> str:
    """Apply the first matching ``__ns:=`` rule to a namespace."""
    for rule in rules:
        if rule.source == '__ns' and rule.applies_to(node_name):
            return normalize_namespace(rule.target)
    return normalize_namespace(namespace)


def resolve_topic_name(
    rules: Sequence[RemapRule],
    name: str,
    node_name: str,
    namespace: str,
    original_node_name: str | None = None,
) -> str:
    """Expand a topic name and apply the first topic remap rule that matches it.

    Parameters
    ----------
    rules : Sequence[RemapRule]
        Remap rules in command-line order; ``__ns`` and ``__node`` rules are skipped.
    name : str
        Topic name as the node code gives it.
    node_name : str
        The node's (possibly remapped) name, used for expansion.
    namespace : str
        The node's (possibly remapped) namespace.
    original_node_name : str or None
        The node's name before remapping, which node-targeted rules name (default: node_name).

    Returns
    -------
    str
        The fully qualified, remapped topic name.

    """
    expanded = expand_topic_name(name, node_name, namespace)
    target_node = original_node_name or node_name
    for rule in rules:
        if rule.source in ('__ns', '__node') or not rule.applies_to(target_node):
            continue
        if expand_topic_name(rule.source, node_name, namespace) == expanded:
            return expand_topic_name(rule.target, node_name, namespace)
    return expanded
