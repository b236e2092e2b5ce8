"""Tests of the discovery take of the standalone context under a SIGINT."""

from __future__ import annotations

import os
import signal
import time

import pytest

from exo_has_runtime.standalone.context import _take_holding_sigint


class _Reader:
    """A discovery reader interrupted by a SIGINT while it builds a sample.

    As the DDS binding does, an exception raised in the sample constructor comes out as a bare
    Exception.
    """

    def take(self, N: int) -> list[int]:  # noqa: N803 (the binding's keyword)
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)  # Python runs the handler here, in the "constructor"
        except BaseException:
            raise Exception('Callfunc endpoint constructor errored') from None
        return list(range(min(N, 3)))


def test_a_sigint_during_a_discovery_take_is_raised_after_it_as_a_keyboard_interrupt() -> None:
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        _take_holding_sigint(_Reader())
    assert signal.getsignal(signal.SIGINT) is handler


def test_a_discovery_take_without_a_signal_returns_its_samples() -> None:
    class Quiet:
        def take(self, N: int) -> list[int]:  # noqa: N803
            return [1, 2]

    assert _take_holding_sigint(Quiet()) == [1, 2]
