"""A stop asked for by signals: a flag set without a lock, and a wait that sees it."""

from __future__ import annotations

import signal
import time

from exo_has_common.stopping import StopRequest, stop_on_signals


def test_a_stop_set_by_a_signal_ends_the_wait_early() -> None:
    stop = StopRequest()
    previous = signal.signal(signal.SIGALRM, stop)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        started = time.monotonic()
        assert stop.wait(5.0)
        assert time.monotonic() - started < 1.0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def test_a_wait_without_a_stop_lasts_its_timeout_and_says_so() -> None:
    started = time.monotonic()
    assert not StopRequest().wait(0.12)
    assert time.monotonic() - started >= 0.12


def test_stop_on_signals_installs_the_request_as_the_handler() -> None:
    previous = {n: signal.getsignal(n) for n in (signal.SIGUSR1,)}
    try:
        stop = stop_on_signals((signal.SIGUSR1,))
        signal.raise_signal(signal.SIGUSR1)
        assert stop.is_set()
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
