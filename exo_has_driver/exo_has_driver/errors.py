"""Exceptions of exo_has_driver; every error it raises on purpose is a :class:`DriverError`."""

from __future__ import annotations


class DriverError(Exception):
    """Base of the errors raised by exo_has_driver."""


class SafetyConfigError(DriverError, ValueError):
    """A safety limit or watchdog setting that is missing, unknown or out of range."""
