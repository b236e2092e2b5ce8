"""Exceptions of exo_has_driver; every error it raises on purpose is a :class:`DriverError`."""

from __future__ import annotations

from exo_has_common.errors import ExoHasError


class DriverError(ExoHasError):
    """Base of the errors raised by exo_has_driver."""


class SafetyConfigError(DriverError, ValueError):
    """A safety limit or watchdog setting that is missing, unknown or out of range."""


class DeviceError(DriverError):
    """A simulated CANopen device (exo_has_driver.devices) misconfigured or misused."""


class SdoAbortError(DeviceError):
    """An SDO request a simulated device refuses, with its CiA 301 abort code.

    Parameters
    ----------
    code : int
        The CiA 301 SDO abort code sent to the client (e.g. 0x06010002, read-only object).
    message : str
        What was refused and why.

    """

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


class FaultInjectionError(DeviceError, ValueError):
    """A fault injection naming an unknown joint, device or channel, or a bad value."""


class HardwareConfigError(DriverError, ValueError):
    """A hardware driver setting (units, node IDs, timing) that is missing or out of range."""


class CanBusError(DriverError, OSError):
    """The CAN bus cannot be opened or used (unknown interface, missing channel, bus down)."""


class CanOpenError(DriverError, OSError):
    """A CANopen device answered wrongly at start: SDO abort, wrong identity, refused state."""


class CanOpenTimeoutError(CanOpenError, TimeoutError):
    """A CANopen device did not answer in time (SDO response, boot-up, NMT state, enable)."""


class MasterStoppedError(DriverError):
    """The CANopen master's I/O thread ended while running: the driver cannot go on."""
