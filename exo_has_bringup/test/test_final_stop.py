import math

from exo_has_bringup.analysis import RecordedEvent, final_stop
from exo_has_bringup.demo import FAILED, STOPPED, Outcome
from exo_has_driver.events import SafetyKind, Severity


def event(t, kind, severity, latched, text='', joint='left_hip'):
    return RecordedEvent(t, joint, int(kind), int(severity), math.nan, math.nan, latched, text)


FATAL = event(1.0, SafetyKind.STALE_STATE, Severity.FATAL, True, 'left_hip: stale state')
RELEASED = event(3.0, SafetyKind.RESET, Severity.INFO, False, 'reset: stop released', '')


def test_a_record_without_events_or_with_warnings_only_ended_in_no_stop():
    assert final_stop([]) is None
    assert final_stop([event(1.0, SafetyKind.OVER_PRESSURE, Severity.WARN, False)]) is None


def test_a_fatal_event_never_reset_is_the_stop_the_session_ended_in():
    later = event(2.0, SafetyKind.STROKE_END, Severity.FATAL, True, 'left_knee: stroke end')
    assert final_stop([later, FATAL]) == FATAL  # the first, whatever the order of reception


def test_a_released_stop_is_over_and_a_later_fatal_event_is_the_new_stop():
    assert final_stop([FATAL, RELEASED]) is None
    again = event(5.0, SafetyKind.SECOND_SOURCE, Severity.FATAL, True, 'second source')
    assert final_stop([FATAL, RELEASED, again]) == again


def test_a_release_refused_by_another_source_leaves_the_stop_in_place():
    # The watchdog released; the driver refused, its drive still in fault (latched WARN).
    refused = event(3.1, SafetyKind.DRIVE_FAULT, Severity.WARN, True, 'reset refused: fault')
    assert final_stop([FATAL, RELEASED, refused]) == FATAL


def test_a_hold_on_a_lost_reference_is_not_a_stop():
    hold = event(2.0, SafetyKind.STALE_REFERENCE, Severity.ERROR, True, 'stale reference', '')
    assert final_stop([hold]) is None


def test_the_demo_exits_non_zero_after_a_stop_and_after_a_node_that_failed(tmp_path):
    report = tmp_path / 'report.md'
    assert Outcome(report, None, {}).status == 0
    assert Outcome(report, FATAL, {}).status == STOPPED
    assert Outcome(report, None, {'watchdog': -9}).status == FAILED
    assert Outcome(report, FATAL, {'watchdog': -9}).status == STOPPED
    assert STOPPED not in (0, FAILED)
