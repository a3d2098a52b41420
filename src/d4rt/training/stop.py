"""Stopping a training run cleanly on SIGTERM or SIGINT (cluster preemption, ``kill``, Ctrl-C).

The first signal only sets a flag: the trainer finishes the optimiser step it is in, writes a checkpoint
at that step and returns, so ``d4rt train --resume`` continues exactly where it stopped (bitwise on the
CPU, like any other checkpoint). A second signal stops at once, the default way. Only the process that
receives the signal sees it; under torchrun the ranks agree on stopping (any rank's flag stops all).

A signal to the whole process group (``timeout``, Ctrl-C in a shell, a scheduler's preemption) reaches
the data-loading workers too. They leave stopping to the main process (:func:`defer_stop_signals`): killed,
they would take the batches of the step being finished with them, and the run would end with an error
instead of a checkpoint.
"""

from __future__ import annotations

import signal
import threading

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class StopRequest:
    """Context manager that turns the first SIGTERM / SIGINT into ``requested`` (the signal's name).

    Handlers are installed only in the main thread (Python allows no other) and restored on exit.
    """

    def __init__(self):
        self.requested: str | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "StopRequest":
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame) -> None:
        if self.requested is not None:  # asked twice: stop now, as without this handler
            signal.signal(signum, self._previous[signum])
            signal.raise_signal(signum)
            return
        self.requested = signal.Signals(signum).name

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()


def defer_stop_signals() -> None:
    """In a data-loading worker (called by its ``worker_init_fn``): ignore the first SIGTERM / SIGINT.

    The main process sees the same signal when it went to the process group; it finishes its step and
    shuts the loader down, which ends the workers. A second signal acts the default way, as in the main
    process (SIGTERM ends the worker; SIGINT raises KeyboardInterrupt, which ends torch's worker loop), so
    a second signal to the group still stops everything at once and the loader's ``terminate()`` of a
    worker that does not finish in time still works. Workers whose main process died end on their own
    (torch's watchdog).
    """
    if threading.current_thread() is not threading.main_thread():
        return
    received: list[int] = []

    def handle(signum: int, frame) -> None:
        if received:  # asked twice: stop now, the default way
            for sig, default in ((signal.SIGTERM, signal.SIG_DFL), (signal.SIGINT, signal.default_int_handler)):
                signal.signal(sig, default)
            signal.raise_signal(signum)
            return
        received.append(signum)

    for sig in STOP_SIGNALS:
        signal.signal(sig, handle)


def exit_status(stopped_by: str) -> int:
    """The shell's status of a process ended by the named signal (128 + its number; 1 if not a signal)."""
    return 128 + int(signal.Signals[stopped_by]) if stopped_by in signal.Signals.__members__ else 1
