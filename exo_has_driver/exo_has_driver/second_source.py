"""A second source: more publishers on a joint's state or command topic than the one allowed.

Free of ROS. A joint's states have one source (its plant, or the hardware driver) and its
commands one commander (the controller); the nodes that may send stop commands beside it (the
watchdog, for the driver its ``stop_sources``) do not count. Any other publisher (a second plant
or driver, a second controller, a replay, a test node left over) is one the other rules cannot
tell from the real one: a SECOND_SOURCE fault. The watchdog's core (through
:class:`exo_has_driver.joint_watch.JointWatch`) and the driver node judge the publishers that
the ROS graph shows with the one rule, :func:`second_source`.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from exo_has_driver.events import Condition, SafetyKind


def second_source(joint: str, topic: str, publishers: Sequence[str], *,
                  stop_sources: Collection[str] = (), own: str | None = None) -> Condition | None:
    """Return the SECOND_SOURCE condition of one of a joint's topics; None with one source.

    Parameters
    ----------
    joint : str
        The joint.
    topic : str
        Its state or command topic.
    publishers : Sequence[str]
        One name per publisher on the topic (its node's full name), the caller's own left out.
    stop_sources : Collection[str]
        Full names of the nodes that may publish stop commands beside the one source: not
        counted.
    own : str or None
        How the caller names itself where it is the topic's one source (the driver, on the
        states it publishes: ``'this driver'``); None where it does not publish there.

    Returns
    -------
    Condition or None
        With more than one publisher counted: key ``('second source', topic)``, value the
        number counted, limit 1, the text naming them (sorted, the caller last). None otherwise.

    """
    counted = sorted(name for name in publishers if name not in stop_sources)
    if own is not None:
        counted.append(own)
    if len(counted) <= 1:
        return None
    return Condition(('second source', topic), joint, SafetyKind.SECOND_SOURCE,
                     float(len(counted)), 1.0,
                     f'{joint}: second source: {len(counted)} publishers on {topic} '
                     f'({", ".join(counted)}), where one is allowed')
