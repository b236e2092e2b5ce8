import math

from exo_has_driver.events import CLEAR_TIME, Clearing, Condition, SafetyKind, Severity, StopLatch


def stale(joint='left_hip', age=0.6):
    return Condition((joint, SafetyKind.STALE_STATE), joint, SafetyKind.STALE_STATE, age, 0.5,
                     f'{joint}: stale state: no state for {age} s')


def test_a_fatal_event_latches_the_stop_and_the_first_one_stays_its_cause():
    latch = StopLatch()
    warning = latch.event('left_hip', SafetyKind.OVER_PRESSURE, Severity.WARN, 17e6, 16e6, 'w')
    assert not latch.latched and not warning.latched and latch.cause is None
    first = latch.event('left_hip', SafetyKind.TRACKING_ERROR, Severity.FATAL, 0.4, 0.35, 'a')
    second = latch.event('right_knee', SafetyKind.STALE_STATE, Severity.FATAL, 0.6, 0.5, 'b')
    assert latch.latched and first.latched and second.latched
    assert latch.cause is first
    assert isinstance(first.kind, SafetyKind) and isinstance(first.severity, Severity)


def test_a_lasting_condition_is_reported_once_and_again_after_it_was_forgotten():
    latch = StopLatch()
    (event,) = latch.report_once(stale())
    assert (event.kind, event.severity, event.latched) == (
        SafetyKind.STALE_STATE, Severity.FATAL, True)
    assert latch.report_once(stale(age=0.7)) == []
    assert latch.is_reported(('left_hip', SafetyKind.STALE_STATE))
    latch.forget({('left_hip', SafetyKind.STALE_STATE)})
    assert len(latch.report_once(stale(age=0.8))) == 1


def test_a_reset_is_refused_listing_every_condition_that_holds_and_the_latch_stays():
    latch = StopLatch()
    latch.report_once(stale())
    refusal = latch.refusal([stale(), stale('right_knee', 0.9)])
    assert refusal is not None
    assert (refusal.joint, refusal.kind, refusal.severity, refusal.latched) == (
        'left_hip', SafetyKind.STALE_STATE, Severity.WARN, True)
    assert refusal.text == ('reset refused: left_hip: stale state: no state for 0.6 s; '
                            'right_knee: stale state: no state for 0.9 s')
    assert latch.latched
    assert latch.refusal([]) is None


def test_a_release_names_the_cause_clears_it_and_forgets_the_reported_conditions():
    latch = StopLatch()
    latch.report_once(stale())
    released = latch.release()
    assert (released.kind, released.severity, released.latched) == (
        SafetyKind.RESET, Severity.INFO, False)
    assert released.text == 'reset: stop released (latched by left_hip: stale state: no state ' \
        'for 0.6 s)'
    assert math.isnan(released.value) and not latch.latched and latch.cause is None
    assert latch.reported == frozenset()
    assert latch.release().text == 'reset: no stop was latched'


def test_a_condition_clears_once_absent_for_the_clear_time_from_its_first_absence():
    clearing = Clearing()
    clearing.absent('stale', 1.0)
    clearing.absent('stale', 1.1)  # still absent: counted from 1.0
    assert clearing.due(1.0 + CLEAR_TIME - 0.01) == set()
    assert clearing.due(1.0 + CLEAR_TIME) == {'stale'}
    assert clearing.due(5.0) == set()  # reported once


def test_a_condition_that_holds_again_or_is_forgotten_does_not_clear():
    clearing = Clearing()
    clearing.absent('valve', 0.0)
    clearing.absent('pressure', 0.0)
    clearing.holds('valve')
    clearing.holds('pressure')
    clearing.absent('valve', 0.2)  # absent anew: counted from 0.2
    assert clearing.due(CLEAR_TIME) == set()
    assert clearing.due(0.2 + CLEAR_TIME) == {'valve'}
