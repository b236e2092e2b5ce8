from pathlib import Path

import pytest

from exo_has_common.errors import CommandLineError
from exo_has_common.params_yaml import load_yaml, read_yaml_file


def test_exponents_without_a_dot_or_sign_are_read_as_doubles_as_rcl_reads_them():
    document = load_yaml('a: 1e9\nb: 1.0e9\nc: -2.5E-3\nd: 7\ne: 1e9x\n')
    assert document == {'a': 1e9, 'b': 1e9, 'c': -2.5e-3, 'd': 7, 'e': '1e9x'}
    assert isinstance(document['a'], float)


def test_a_file_that_is_not_yaml_is_named_in_the_error(tmp_path: Path):
    path = tmp_path / 'bad.yaml'
    path.write_text('a: [1, 2\n', encoding='utf-8')
    with pytest.raises(CommandLineError, match=r'parameters file .*bad\.yaml is not valid YAML'):
        read_yaml_file(path)


def test_a_missing_file_is_named_in_the_error(tmp_path: Path):
    with pytest.raises(CommandLineError, match=r'cannot read parameters file .*none\.yaml'):
        read_yaml_file(tmp_path / 'none.yaml')
