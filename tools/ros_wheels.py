"""Mend the ROS 2 Jazzy wheels from PyPI so that rosidl can build exo_has_msgs against them.

Run by ``./run`` with the project's ``.venv`` interpreter after every install; it changes only
files of that environment and is idempotent.

The message wheels (``ros-jazzy-std-msgs`` and the rest) ship the CMake export files of their
Python type support, ``share/<pkg>/cmake/export_<pkg>__rosidl_generator_pyExport.cmake``, with
the include directories of the machine that built them: ``/opt/python/cp3XX-cp3XX/include/
python3.XX`` and that interpreter's numpy include directory. ``rosidl_generate_interfaces``
links our messages' Python type support against those targets, and CMake refuses an imported
target whose include directory does not exist. This points them at this interpreter's headers
and numpy's. Anything else in those lines (a new wheel release that fixed or changed them)
stops the set-up with a message, rather than being rewritten blindly.
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

import numpy

#: The property line rewritten, and the two builder paths it is known to carry.
_LINE = re.compile(r'^(\s*INTERFACE_INCLUDE_DIRECTORIES ")([^"]*)(")\s*$', re.MULTILINE)
_BUILDER_PYTHON = re.compile(r'^/opt/python/cp3\d+-cp3\d+/include/python3\.\d+$')
_BUILDER_NUMPY = re.compile(
    r'^/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include$')


class WheelLayoutError(RuntimeError):
    """The wheels are not laid out as this mend expects: it must be looked at again."""


def mend_export_file(path: Path, python_include: str, numpy_include: str) -> bool:
    """Point one export file's include directories at this machine's; return whether it changed.

    Raises
    ------
    WheelLayoutError
        If the file has no include line, or one with paths other than the builder's or ours.

    """
    text = path.read_text(encoding='utf-8')
    matches = list(_LINE.finditer(text))
    if len(matches) != 1:
        msg = (f'{path}: expected one INTERFACE_INCLUDE_DIRECTORIES line, found '
               f'{len(matches)}; the ROS 2 wheels changed, review tools/ros_wheels.py')
        raise WheelLayoutError(msg)
    entries = matches[0].group(2).split(';')
    wanted = [python_include, numpy_include]
    if entries == wanted:
        return False
    if len(entries) != 2 or not _BUILDER_PYTHON.match(entries[0]) \
            or not _BUILDER_NUMPY.match(entries[1]):
        msg = (f"{path}: include directories {entries} are neither the wheel builder's "
               f"(/opt/python/...) nor this machine's; the ROS 2 wheels changed, review "
               'tools/ros_wheels.py')
        raise WheelLayoutError(msg)
    start, end = matches[0].span(2)
    path.write_text(text[:start] + ';'.join(wanted) + text[end:], encoding='utf-8')
    return True


def mend(prefix: Path) -> int:
    """Mend every message package's export file under ``prefix/share``; return how many changed.

    Raises
    ------
    WheelLayoutError
        If there are none (the wheels moved them) or one is not as expected.

    """
    files = sorted(prefix.glob('share/*/cmake/export_*__rosidl_generator_pyExport.cmake'))
    if not any(f.parts[-3] == 'std_msgs' for f in files):
        msg = (f'no std_msgs Python type-support export file under {prefix}/share: the ROS 2 '
               'wheels changed, review tools/ros_wheels.py')
        raise WheelLayoutError(msg)
    python_include = sysconfig.get_paths()['include']
    if not Path(python_include, 'Python.h').is_file():
        msg = (f'no Python.h in {python_include}: install the Python headers '
               f'(Debian: python3-dev) for {sys.executable}')
        raise WheelLayoutError(msg)
    return sum(mend_export_file(f, python_include, numpy.get_include()) for f in files)


def main() -> int:
    """Mend the wheels of the running interpreter's prefix."""
    try:
        changed = mend(Path(sys.prefix))
    except WheelLayoutError as exc:
        print(f'ros_wheels: {exc}', file=sys.stderr)
        return 1
    if changed:
        print(f'ros_wheels: pointed {changed} message export files at this interpreter',
              file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
