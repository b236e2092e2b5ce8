import os
import subprocess
import sys
import tempfile

import pytest

from exo_has_runtime.errors import BackendError
from exo_has_runtime.standalone.context import domain_id_from_environment


def import_runtime(backend):
    env = {**os.environ, 'EXO_HAS_BACKEND': backend}
    return subprocess.run([sys.executable, '-c', 'import exo_has_runtime as r; print(r.BACKEND)'],
                          capture_output=True, text=True, env=env, cwd=tempfile.gettempdir(),
                          check=False)


def test_without_rclpy_the_standalone_backend_is_chosen():
    result = import_runtime('auto')
    assert result.returncode == 0 and result.stdout.strip() == 'standalone'


@pytest.mark.parametrize(('backend', 'message'), [
    ('rclpy', 'EXO_HAS_BACKEND=rclpy but rclpy cannot be imported: source ROS 2'),
    ('zenoh', "EXO_HAS_BACKEND='zenoh': expected auto, rclpy or standalone"),
])
def test_an_impossible_backend_request_fails_at_import_naming_the_variable(backend, message):
    result = import_runtime(backend)
    assert result.returncode != 0 and message in result.stderr


@pytest.mark.parametrize(('value', 'expected'), [('', 0), ('0', 0), ('42', 42), (' 7 ', 7)])
def test_ros_domain_id_is_read_from_the_environment(monkeypatch, value, expected):
    monkeypatch.setenv('ROS_DOMAIN_ID', value)
    assert domain_id_from_environment() == expected


@pytest.mark.parametrize('value', ['-1', '233', 'one', '1.5'])
def test_an_invalid_ros_domain_id_is_named_in_the_error(monkeypatch, value):
    monkeypatch.setenv('ROS_DOMAIN_ID', value)
    with pytest.raises(BackendError, match=r'ROS_DOMAIN_ID=.*expected a whole number'):
        domain_id_from_environment()
