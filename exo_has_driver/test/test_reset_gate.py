"""The driver's reset gate, free of ROS: a reset waits while another node's stop holds."""

from exo_has_driver.reset_gate import ResetGate


def test_the_reset_gate_passes_a_reset_only_when_no_other_node_holds_a_stop():
    gate = ResetGate(wait=1.0)
    assert gate.on_reset(10.0)  # nothing latched elsewhere: at once
    assert not gate.on_event(True, 'watchdog: stale state')
    assert not gate.on_reset(11.0)  # waits for the watchdog's answer to the same reset
    assert gate.expired(11.5) is None
    assert gate.on_event(False, 'reset: stop released')  # released: the reset goes on
    assert gate.expired(13.0) is None
    gate.on_event(True, 'watchdog: stale state')
    assert not gate.on_reset(20.0)
    assert not gate.on_event(True, 'reset refused: stale state holds')
    assert gate.expired(21.5) == ('reset refused: a stop latched by another node holds: '
                                  'reset refused: stale state holds')
    assert not gate.on_event(False, 'reset: stop released')  # no reset waits any more


def test_a_reset_with_nothing_latched_elsewhere_goes_on_at_once_and_waits_for_nothing():
    gate = ResetGate(wait=1.0)
    gate.on_event(False, 'reset: no stop was latched')
    assert gate.on_reset(5.0)
    assert gate.expired(100.0) is None
    assert gate.latched_by is None
