"""Stopping a training run cleanly on SIGTERM or SIGINT (cluster preemption, ``kill``, Ctrl-C).

The first signal only sets a flag: the trainer finishes the optimiser step it is in, writes a checkpoint
at that step and returns, so ``d4rt train --resume`` continues exactly where it stopped (bitwise on the
CPU, like any other checkpoint). A second signal stops at once, the default way. Only the process that
receives the signal sees it; under torchrun the ranks agree on stopping (any rank's flag stops all).
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


def exit_status(stopped_by: str) -> int:
    """The shell's status of a process ended by the named signal (128 + its number; 1 if not a signal)."""
    return 128 + int(signal.Signals[stopped_by]) if stopped_by in signal.Signals.__members__ else 1
