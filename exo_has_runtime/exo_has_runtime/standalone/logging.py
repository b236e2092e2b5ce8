"""Loggers shaped as rclpy's: ``node.get_logger().info('...')`` with severities and filters.

Lines go to standard error as rcutils formats them by default:
``[LEVEL] [seconds.nanoseconds] [logger]: message``.
"""

from __future__ import annotations

import sys
import time
from enum import IntEnum
from typing import TextIO


class LoggingSeverity(IntEnum):
    """Severities, numbered as rcutils."""

    UNSET = 0
    DEBUG = 10
    INFO = 20
    WARN = 30
    ERROR = 40
    FATAL = 50


_DEFAULT_LEVELS: dict[str, LoggingSeverity] = {}


def set_default_levels(levels: dict[str, str]) -> None:
    """Set logger levels from ``--log-level`` arguments ('' is the default for every logger)."""
    for name, level in levels.items():
        _DEFAULT_LEVELS[name] = LoggingSeverity[level.upper()]


class RcutilsLogger:
    """A named logger; child loggers are named ``parent.child``.

    Parameters
    ----------
    name : str
        Logger name (a node's logger is named after the node, namespace dots included).
    stream : TextIO or None
        Where lines go (default: standard error).

    """

    def __init__(self, name: str = '', stream: TextIO | None = None) -> None:
        self.name = name
        self._stream = stream
        self._level = LoggingSeverity.UNSET
        self._once: set[tuple[int, str]] = set()
        self._last: dict[tuple[int, str], float] = {}

    def get_child(self, name: str) -> RcutilsLogger:
        """Return the logger ``<this name>.<name>``."""
        return RcutilsLogger(f'{self.name}.{name}' if self.name else name, self._stream)

    def set_level(self, level: LoggingSeverity) -> None:
        """Set this logger's threshold."""
        self._level = LoggingSeverity(level)

    def get_effective_level(self) -> LoggingSeverity:
        """Return the threshold in force (own, else from ``--log-level``, else INFO)."""
        if self._level != LoggingSeverity.UNSET:
            return self._level
        name = self.name
        while name:  # 'exo.left_hip' inherits the level set for 'exo'
            if name in _DEFAULT_LEVELS:
                return _DEFAULT_LEVELS[name]
            name = name.rpartition('.')[0]
        return _DEFAULT_LEVELS.get('', LoggingSeverity.INFO)

    def is_enabled_for(self, severity: LoggingSeverity) -> bool:
        """Tell whether a message of this severity would be written."""
        return severity >= self.get_effective_level()

    def log(self, message: str, severity: LoggingSeverity, *, once: bool = False,
            throttle_duration_sec: float | None = None, skip_first: bool = False) -> bool:
        """Write a message if the severity and the filters allow it; return whether it was."""
        if not self.is_enabled_for(severity):
            return False
        caller = sys._getframe(2)  # the line that called debug(), info(), ...
        key = (int(severity), f'{caller.f_code.co_filename}:{caller.f_lineno}')
        if once:
            if key in self._once:
                return False
            self._once.add(key)
        now = time.monotonic()
        if skip_first and key not in self._last:
            self._last[key] = now
            return False
        if throttle_duration_sec is not None:
            last = self._last.get(key)
            if last is not None and now - last < throttle_duration_sec:
                return False
        self._last[key] = now
        stamp = time.time()
        stream = self._stream if self._stream is not None else sys.stderr
        stream.write(f'[{severity.name}] [{stamp:.9f}] [{self.name}]: {message}\n')
        stream.flush()
        return True

    def debug(self, message: str, **kwargs: object) -> bool:
        """Log at DEBUG."""
        return self.log(message, LoggingSeverity.DEBUG, **kwargs)  # type: ignore[arg-type]

    def info(self, message: str, **kwargs: object) -> bool:
        """Log at INFO."""
        return self.log(message, LoggingSeverity.INFO, **kwargs)  # type: ignore[arg-type]

    def warning(self, message: str, **kwargs: object) -> bool:
        """Log at WARN."""
        return self.log(message, LoggingSeverity.WARN, **kwargs)  # type: ignore[arg-type]

    warn = warning

    def error(self, message: str, **kwargs: object) -> bool:
        """Log at ERROR."""
        return self.log(message, LoggingSeverity.ERROR, **kwargs)  # type: ignore[arg-type]

    def fatal(self, message: str, **kwargs: object) -> bool:
        """Log at FATAL."""
        return self.log(message, LoggingSeverity.FATAL, **kwargs)  # type: ignore[arg-type]


def get_logger(name: str) -> RcutilsLogger:
    """Return a logger of this name, as ``rclpy.logging.get_logger``."""
    return RcutilsLogger(name)
