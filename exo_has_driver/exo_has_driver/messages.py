"""A safety event as exo_has_msgs/msg/SafetyEvent, and as a log line.

ROS-facing: the watchdog node and the driver node publish and log the events of their cores
(:class:`~exo_has_driver.events.Event`) through these, the one place that knows the message.
"""

from __future__ import annotations

from rclpy.impl.rcutils_logger import RcutilsLogger

from exo_has_driver.events import Event, Severity
from exo_has_msgs.msg import SafetyEvent
from exo_has_sim.state_message import set_stamp


def safety_event(event: Event, stamp_ns: int) -> SafetyEvent:
    """Return the SafetyEvent message of an event, stamped ``stamp_ns`` [ns]."""
    message = SafetyEvent(joint=event.joint, kind=event.kind, severity=event.severity,
                          value=event.value, limit=event.limit, latched=event.latched,
                          text=event.text, phase=event.phase)
    set_stamp(message.header, stamp_ns)
    return message


def log_event(logger: RcutilsLogger, event: Event) -> None:
    """Log an event's text at its severity: ERROR and FATAL as errors, WARN, else INFO."""
    if event.severity >= Severity.ERROR:
        logger.error(event.text)
    elif event.severity == Severity.WARN:
        logger.warning(event.text)
    else:
        logger.info(event.text)
