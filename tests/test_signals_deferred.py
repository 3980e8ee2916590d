"""``signals_deferred``: SIGINT, SIGTERM and SIGHUP held back while a pair of files is published, then delivered.

The handlers were swapped for a recorder before the block's ``try``: a signal that came between two swaps, its own
handler raising (``pmw``'s SIGTERM raises ``Terminated``), left the signals already swapped with the recorder for
good, so a later Ctrl-C was recorded and never acted on (helper-149's reading of the code).
"""

from __future__ import annotations

import os
import signal

import pytest

from pmwm_codec import atomic


class Stop(Exception):
    pass


@pytest.fixture
def handlers():
    """The three signals' handlers as the test found them, put back after it; SIGTERM raising :class:`Stop`."""
    saved = {sig: signal.getsignal(sig) for sig in atomic._DEFERRED_SIGNALS}

    def stop(signum, frame):
        raise Stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    yield {sig: signal.getsignal(sig) for sig in saved}
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def test_a_signal_between_two_swaps_leaves_every_handler_as_it_was(handlers, monkeypatch):
    real = signal.signal
    swapped = []

    def swap(sig, handler):  # SIGTERM comes right after the first swap, before its own
        previous = real(sig, handler)
        swapped.append(sig)
        if len(swapped) == 1:
            os.kill(os.getpid(), signal.SIGTERM if sig != signal.SIGTERM else signal.SIGHUP)
        return previous

    monkeypatch.setattr(atomic.signal, "signal", swap)
    first = sorted(atomic._DEFERRED_SIGNALS, key=list(atomic._DEFERRED_SIGNALS).index)[0]
    assert first != signal.SIGTERM  # (the set's order: SIGTERM is not swapped first, so its handler raises)
    with pytest.raises(Stop):
        with atomic.signals_deferred():
            pytest.fail("the block ran although SIGTERM stopped the swap")
    monkeypatch.undo()
    assert {sig: signal.getsignal(sig) for sig in handlers} == handlers


def test_signals_held_in_the_block_are_delivered_when_it_ends(handlers):
    with pytest.raises(Stop):
        with atomic.signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGHUP)  # ignored before: ignored after
            for _ in range(1000):  # (the handlers run between bytecodes: they have run by now)
                pass
            held = True
    assert held
    assert {sig: signal.getsignal(sig) for sig in handlers} == handlers


def test_a_recorder_a_stopped_restore_left_behind_acts_as_the_signals_own_handler(handlers):
    """A signal that stops the restore (its handler, restored, raising) leaves the signals not yet restored with
    the recorder: once the block has ended it hands each signal to that signal's own handler."""
    with pytest.raises(KeyboardInterrupt):
        with atomic.signals_deferred():
            recorder = signal.getsignal(signal.SIGINT)
        recorder(signal.SIGINT, None)  # (as if SIGINT came while its recorder was still installed)
