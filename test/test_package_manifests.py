"""Every package.xml declares what its package imports.

The Python code of each ament_python package is read with :mod:`ast` (nothing is imported): the
modules that ``<pkg>/<pkg>/`` imports must be an ``<exec_depend>`` or ``<depend>`` of its
package.xml, and those that ``<pkg>/test/`` imports one of these or a ``<test_depend>``. The
standard library, the package itself and the modules beside the importing file (a test module
that imports a sibling one) are left out; a module becomes its rosdep key through
``ROSDEP_KEYS`` or, for a ROS package, keeps its name.

Not in rosdep's base yaml (rosdistro's ``rosdep/python.yaml`` as of August 2026), as far as we
know: ``python3-canopen`` (rosdistro has ``canopen-pip``), ``python3-mcap``,
``python3-rosbags`` (rosdistro has ``python3-rosbags-pip``) and ``python3-lz4``. ``rosdep
install`` cannot resolve them (skip them with ``--skip-keys``); requirements.txt installs them
with pip.

Imports computed at run time (``importlib.import_module`` in exo_has_runtime's container and
message_types) are not seen.
"""

import ast
import functools
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

WORKSPACE = Path(__file__).resolve().parents[1]
PYTHON_PACKAGES = ('exo_has_common', 'exo_has_runtime', 'exo_has_sim', 'exo_has_control',
                   'exo_has_driver', 'exo_has_bringup')

# The rosdep key of each top-level module that is not a ROS package of the same name.
ROSDEP_KEYS = {
    'can': 'python3-can',
    'canopen': 'python3-canopen',
    'dask': 'python3-dask',
    'lz4': 'python3-lz4',
    'matplotlib': 'python3-matplotlib',
    'mcap': 'python3-mcap',
    'numba': 'python3-numba',
    'numpy': 'python3-numpy',
    'pytest': 'python3-pytest',
    'rosbags': 'python3-rosbags',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
}

# Which tags of package.xml satisfy an import of the package's code, and of its tests.
RUN_TAGS = ('depend', 'exec_depend')
TEST_TAGS = (*RUN_TAGS, 'test_depend')


def statements(body):
    """Yield the statements of a body and, depth first, those of the bodies they hold.

    Parameters
    ----------
    body : list[ast.AST]
        A module's, function's, class's or compound statement's ``body``.

    Yields
    ------
    ast.AST
        Each statement, and each ``except`` handler and ``case`` clause (these hold bodies).
    """
    for statement in body:
        yield statement
        for field in ('body', 'orelse', 'finalbody', 'handlers', 'cases'):
            yield from statements(getattr(statement, field, ()))


def imported_modules(source):
    """Return the top-level modules a Python source imports, wherever the import statement is.

    Imports inside functions, classes, ``try`` blocks and ``if TYPE_CHECKING:`` count as well.
    Those under ``if TYPE_CHECKING:`` alone are never executed and could be left out; none is
    today (bags/qos.py imports rosbags at run time too), so the walk keeps them and stays simple.
    An import is a statement: the walk visits statements only, not the expressions that make
    most of a tree, which keeps the whole workspace's scan to a fraction of a second.

    Parameters
    ----------
    source : str
        The text of a Python module.

    Returns
    -------
    set[str]
        The first component of every absolute import; relative imports are left out.
    """
    modules = set()
    for node in statements(ast.parse(source).body):
        if isinstance(node, ast.Import):
            modules.update(alias.name.partition('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules.add(node.module.partition('.')[0])
    return modules


@functools.cache
def third_party_imports(package, folder):
    """Return the rosdep key of each module that the code in a folder takes from elsewhere.

    Parameters
    ----------
    package : str
        The package the folder belongs to; its own imports are left out.
    folder : pathlib.Path
        The folder whose ``*.py`` files, at any depth, are read.

    Returns
    -------
    dict[str, set[str]]
        For each rosdep key, the files (relative to the workspace) that import its module.
    """
    keys = {}
    for path in sorted(folder.rglob('*.py')):
        beside = {p.stem if p.suffix == '.py' else p.name for p in path.parent.iterdir()}
        for module in imported_modules(path.read_text(encoding='utf-8')):
            if module in sys.stdlib_module_names or module == package or module in beside:
                continue
            key = ROSDEP_KEYS.get(module, module)
            keys.setdefault(key, set()).add(path.relative_to(WORKSPACE).as_posix())
    return keys


def declared(manifest, tags):
    """Return the dependencies that a package.xml declares with the given tags.

    Parameters
    ----------
    manifest : str
        The text of a package.xml.
    tags : tuple[str, ...]
        The dependency tags to collect, e.g. ``('depend', 'exec_depend')``.

    Returns
    -------
    set[str]
        The declared keys.
    """
    root = ET.fromstring(manifest)
    return {(element.text or '').strip() for tag in tags for element in root.findall(tag)}


def undeclared_imports(package, manifest):
    """Return a line for each import of a package's code that its package.xml does not declare.

    Parameters
    ----------
    package : str
        The name of an ament_python package of the workspace.
    manifest : str
        The text of its package.xml.

    Returns
    -------
    list[str]
        ``'<package>: <tag> <key> (<module>) for <file>'`` for each undeclared import.
    """
    modules = {key: module for module, key in ROSDEP_KEYS.items()}
    run_imports = third_party_imports(package, WORKSPACE / package / package)
    test_imports = third_party_imports(package, WORKSPACE / package / 'test')
    lines = []
    # A test import of what the code imports too is an <exec_depend>'s matter, told once.
    for imports, tags in ((run_imports, RUN_TAGS), (test_imports, TEST_TAGS)):
        keys = declared(manifest, tags)
        tag = tags[-1]
        for key, paths in sorted(imports.items()):
            if key not in keys and (imports is run_imports or key not in run_imports):
                lines.extend(f'{package}: <{tag}>{key}</{tag}> ({modules.get(key, key)}) for '
                             f'{path}' for path in sorted(paths))
    return lines


def test_every_package_declares_what_its_code_imports():
    missing = []
    for package in PYTHON_PACKAGES:
        manifest = (WORKSPACE / package / 'package.xml').read_text(encoding='utf-8')
        missing.extend(undeclared_imports(package, manifest))
    if missing:
        pytest.fail('imports that package.xml does not declare (a PyPI package needs its rosdep '
                    'key in ROSDEP_KEYS):\n' + '\n'.join(missing), pytrace=False)


def test_the_imports_of_functions_and_type_checking_blocks_count_and_relative_ones_do_not():
    source = '\n'.join([
        'import os.path, numpy.linalg as la',
        'from typing import TYPE_CHECKING',
        'from . import sibling',
        'from .plant import Plant',
        'if TYPE_CHECKING:',
        '    from rosbags.typesys import Stores',
        'class Node:',
        '    def main(self):',
        '        import rclpy',
        '        with open(0) as f:',
        '            from exo_has_msgs.msg import HasState',
        'try:',
        '    import scipy',
        'except ImportError:',
        '    import mcap',
        'else:',
        '    import yaml',
        'finally:',
        '    import can',
        'match 1:',
        '    case 1:',
        '        for _ in ():',
        '            while True:',
        '                import canopen',
    ])
    assert imported_modules(source) == {
        'os', 'numpy', 'typing', 'rosbags', 'rclpy', 'exo_has_msgs', 'scipy', 'mcap', 'yaml',
        'can', 'canopen'}


def test_every_package_has_code_that_imports_something():
    for package in PYTHON_PACKAGES:
        assert third_party_imports(package, WORKSPACE / package / package), package
        assert third_party_imports(package, WORKSPACE / package / 'test'), package
