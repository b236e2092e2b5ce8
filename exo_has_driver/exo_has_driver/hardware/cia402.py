"""Master-side CiA 402 logic: which controlword moves a drive toward the wanted state.

Pure functions of the drive state the statusword reports (:func:`decode_state`), the state the
master wants (:class:`Want`) and the controlword sent last, so that the master sends one
controlword per SYNC period and the drive takes one transition per period:

- ``Want.ENABLED``: the enable sequence, switch on disabled --shutdown--> ready to switch on
  --switch on--> switched on --enable operation--> operation enabled;
- ``Want.DISABLED`` (a command with ``enable`` false): the same up to switched on, and from
  operation enabled disable operation (the power stage stays ready, the motor is not driven);
- ``Want.STOPPED`` (the latched stop): from operation enabled quick stop (the drive brakes on its
  quick stop ramp, then, with quick stop option code 2, switches to switch on disabled), held
  while the quick stop is active; from any other state disable voltage.

A drive in fault leaves it only on a rising edge of the fault reset bit, sent only when the
master allows it (``reset_fault``); otherwise, and after the edge, bit 7 stays low, so that the
next allowed reset is again a rising edge. ``quick stop active`` under ``ENABLED`` or
``DISABLED`` is left by disable voltage (quick stop option code 2 allows no return to operation
enabled from it).
"""

from __future__ import annotations

import enum

from exo_has_driver import can_dictionary as cd

NOT_READY = 'not ready to switch on'
SWITCH_ON_DISABLED = 'switch on disabled'
READY_TO_SWITCH_ON = 'ready to switch on'
SWITCHED_ON = 'switched on'
OPERATION_ENABLED = 'operation enabled'
QUICK_STOP_ACTIVE = 'quick stop active'
FAULT_REACTION_ACTIVE = 'fault reaction active'
FAULT = 'fault'
#: A statusword that matches no CiA 402 state (a broken drive or a corrupted PDO).
UNKNOWN = 'unknown'

# Ordered as the CiA 402 table: the first match wins (the order of can_dictionary.STATES).
_STATES = tuple((mask, value, name) for name, (mask, value) in cd.STATES.items())


class Want(enum.Enum):
    """The state the master drives a drive toward."""

    ENABLED = 'enabled'
    DISABLED = 'disabled'
    STOPPED = 'stopped'


def decode_state(statusword: int) -> str:
    """Return the CiA 402 state name of a statusword, :data:`UNKNOWN` when none matches."""
    for mask, value, name in _STATES:
        if statusword & mask == value:
            return name
    return UNKNOWN


def is_fault(state: str) -> bool:
    """Whether a state is fault or fault reaction active."""
    return state in (FAULT, FAULT_REACTION_ACTIVE)


def controlword(state: str, want: Want, last: int, reset_fault: bool = False) -> int:
    """Return the controlword to send next.

    Parameters
    ----------
    state : str
        The drive's state, from :func:`decode_state`.
    want : Want
        Where the master wants the drive.
    last : int
        The controlword sent last (for the fault reset edge).
    reset_fault : bool
        Whether a drive in fault may be reset now.

    Returns
    -------
    int
        One of the ``CW_*`` commands of :mod:`exo_has_driver.can_dictionary`.

    """
    if state == FAULT:
        if reset_fault and not last & cd.CW_FAULT_RESET:
            return cd.CW_FAULT_RESET
        return cd.CW_DISABLE_VOLTAGE
    if state in (FAULT_REACTION_ACTIVE, NOT_READY, UNKNOWN):
        return cd.CW_DISABLE_VOLTAGE
    if want is Want.STOPPED:
        if state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE):
            return cd.CW_QUICK_STOP
        return cd.CW_DISABLE_VOLTAGE
    if state == QUICK_STOP_ACTIVE:
        return cd.CW_DISABLE_VOLTAGE
    if state == SWITCH_ON_DISABLED:
        return cd.CW_SHUTDOWN
    if state == READY_TO_SWITCH_ON:
        return cd.CW_SWITCH_ON
    if state == SWITCHED_ON:
        return cd.CW_ENABLE_OPERATION if want is Want.ENABLED else cd.CW_SWITCH_ON
    # operation enabled
    return cd.CW_ENABLE_OPERATION if want is Want.ENABLED else cd.CW_DISABLE_OPERATION


def reached(state: str, want: Want) -> bool:
    """Whether a drive in ``state`` is where ``want`` leads (stopped: switch on disabled)."""
    if want is Want.ENABLED:
        return state == OPERATION_ENABLED
    if want is Want.DISABLED:
        return state == SWITCHED_ON
    return state == SWITCH_ON_DISABLED
