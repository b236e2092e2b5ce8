import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.cia402 import Want, controlword, decode_state

ENABLED, DISABLED, STOPPED = Want.ENABLED, Want.DISABLED, Want.STOPPED

# What a CiA 402 drive with quick stop option code 2 does with a controlword (the transitions
# of CiA 402's state machine that these tests drive through).
TRANSITIONS = {
    ('switch on disabled', cd.CW_SHUTDOWN): 'ready to switch on',
    ('ready to switch on', cd.CW_SWITCH_ON): 'switched on',
    ('switched on', cd.CW_ENABLE_OPERATION): 'operation enabled',
    ('operation enabled', cd.CW_DISABLE_OPERATION): 'switched on',
    ('operation enabled', cd.CW_QUICK_STOP): 'quick stop active',
    ('quick stop active', cd.CW_QUICK_STOP): 'switch on disabled',  # stopped on the ramp
    ('quick stop active', cd.CW_DISABLE_VOLTAGE): 'switch on disabled',
    ('switched on', cd.CW_DISABLE_VOLTAGE): 'switch on disabled',
    ('ready to switch on', cd.CW_DISABLE_VOLTAGE): 'switch on disabled',
}


def walk(state, want, steps=6, reset_fault=False):
    """Drive a model drive with the master's controlwords; return the states passed."""
    states, last = [state], cd.CW_DISABLE_VOLTAGE
    for _ in range(steps):
        word = controlword(state, want, last, reset_fault)
        if state == 'fault' and word & cd.CW_FAULT_RESET and not last & cd.CW_FAULT_RESET:
            state = 'switch on disabled'
        else:
            state = TRANSITIONS.get((state, word), state)
        last = word
        states.append(state)
    return states


def test_every_statusword_of_the_table_decodes_to_its_state():
    words = {0x0000: 'not ready to switch on', 0x0240: 'switch on disabled',
             0x0231: 'ready to switch on', 0x0233: 'switched on',
             0x0237: 'operation enabled', 0x0217: 'quick stop active',
             0x021F: 'fault reaction active', 0x0218: 'fault'}
    for word, name in words.items():
        assert decode_state(word) == name
    assert decode_state(0x0029) == cia402.UNKNOWN


def test_the_enable_sequence_takes_three_steps_from_switch_on_disabled():
    assert walk('switch on disabled', ENABLED, 4) == [
        'switch on disabled', 'ready to switch on', 'switched on', 'operation enabled',
        'operation enabled']
    assert controlword('operation enabled', ENABLED, cd.CW_ENABLE_OPERATION) == 0x000F


def test_a_disabled_command_leaves_the_drive_switched_on():
    assert walk('operation enabled', DISABLED, 2) == [
        'operation enabled', 'switched on', 'switched on']
    assert walk('switch on disabled', DISABLED, 3)[-1] == 'switched on'


def test_the_stop_quick_stops_an_enabled_drive_then_holds_it_disabled():
    assert controlword('operation enabled', STOPPED, cd.CW_ENABLE_OPERATION) == cd.CW_QUICK_STOP
    assert walk('operation enabled', STOPPED, 3) == [
        'operation enabled', 'quick stop active', 'switch on disabled', 'switch on disabled']
    for state in ('switched on', 'ready to switch on', 'switch on disabled'):
        assert controlword(state, STOPPED, 0) == cd.CW_DISABLE_VOLTAGE


def test_quick_stop_active_is_left_by_disable_voltage_before_enabling_again():
    assert controlword('quick stop active', ENABLED, cd.CW_QUICK_STOP) == cd.CW_DISABLE_VOLTAGE
    assert walk('quick stop active', ENABLED, 4)[-1] == 'operation enabled'


@pytest.mark.parametrize('want', list(Want))
def test_a_fault_is_reset_only_when_allowed_and_only_by_a_rising_edge(want):
    assert controlword('fault', want, 0, reset_fault=False) == cd.CW_DISABLE_VOLTAGE
    assert controlword('fault', want, 0, reset_fault=True) == cd.CW_FAULT_RESET
    # Bit 7 set last time: no second edge until it was low for a period.
    assert controlword('fault', want, cd.CW_FAULT_RESET, reset_fault=True) == 0
    assert controlword('fault reaction active', want, 0, True) == cd.CW_DISABLE_VOLTAGE


def test_a_reset_fault_comes_back_enabled():
    assert walk('fault', ENABLED, 5, reset_fault=True) == [
        'fault', 'switch on disabled', 'ready to switch on', 'switched on',
        'operation enabled', 'operation enabled']
    assert walk('fault', ENABLED, 3, reset_fault=False) == ['fault'] * 4


def test_reached_tells_the_end_state_of_each_want():
    assert cia402.reached('operation enabled', ENABLED)
    assert cia402.reached('switched on', DISABLED)
    assert cia402.reached('switch on disabled', STOPPED)
    assert not cia402.reached('quick stop active', STOPPED)
