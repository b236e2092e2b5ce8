"""Reading ROS 2 parameters files (YAML) the way rcl's parser reads their numbers.

rcl takes ``1e9`` and ``1.0e9`` as doubles; PyYAML follows YAML 1.1, where an exponent needs a
dot and a sign (``1.0e+9``), and would hand ``bulk_modulus: 1.0e9`` over as a string. The HAS
parameter sets are parameters files that a node also takes with ``--params-file``, so both must
read the same numbers.
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from exo_has_common.errors import CommandLineError


class RosYamlLoader(yaml.SafeLoader):
    """YAML loader that reads floats as rcl does: ``1e9`` and ``1.0e9`` are doubles."""


RosYamlLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:\d[\d_]*)?(?:\.\d*)?[eE][-+]?\d+$'),
    list('-+0123456789.'))


def load_yaml(text: str) -> object:
    """Parse YAML text with :class:`RosYamlLoader`."""
    return yaml.load(text, Loader=RosYamlLoader)


def read_yaml_file(path: Path, what: str = 'parameters file') -> object:
    """Read and parse a YAML file with :class:`RosYamlLoader`.

    Raises
    ------
    CommandLineError
        Naming the file when it cannot be read or is not YAML.

    """
    try:
        return load_yaml(path.read_text(encoding='utf-8'))
    except OSError as exc:
        msg = f'cannot read {what} {path}: {exc.strerror}'
        raise CommandLineError(msg) from exc
    except yaml.YAMLError as exc:
        msg = f'{what} {path} is not valid YAML: {exc}'
        raise CommandLineError(msg) from exc
