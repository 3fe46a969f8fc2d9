"""The worker's stop: one flag, set by the first SIGINT or SIGTERM before any part of the worker is torn down, and
the one rule for what an error that ends a job means once it is set.

Once a stop is requested, a running job that ends with an error is handed back (queued again, its attempt not
counted, ``Jobs.hand_back``) instead of failed: the error may be the stop's own doing (the optimiser told to stop
at its next step, a loading process or an encoder session closing under the job, an upload to the store cut
short), and nothing but a run elsewhere tells that from the job's own fault, which then fails it there. A job
that ends without an error while the stop is under way has simply finished first.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


class Stop:
    """Whether this worker is stopping (``request``: the signal handlers), and what that makes of a job's error."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.signum: int | None = None

    def request(self, signum: int) -> bool:
        """Mark the worker stopping by ``signum``; True the first time (a later signal changes nothing)."""
        first = not self._event.is_set()
        if first:
            self.signum = signum
        self._event.set()
        return first

    @property
    def requested(self) -> bool:
        return self._event.is_set()

    @property
    def exit_status(self) -> int:
        """A stopped worker's exit status: 128 + the signal."""
        return 128 + (self.signum or 0)

    @contextlib.contextmanager
    def listening(self) -> Iterator[Stop]:
        """While the worker starts (until rq's loop takes SIGINT and SIGTERM over): a stop signal marks the stop and
        leaves at once (``SystemExit``: no KeyboardInterrupt traceback). Some libraries' imports catch every
        exception, an exit included, so the mark outlives the exit: the worker looks at it before it takes a job. The
        handlers in place before are put back after."""
        previous = {signum: signal.signal(signum, self._leave) for signum in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)

    def _leave(self, signum: int, _frame) -> None:
        self.request(signum)
        raise SystemExit(self.exit_status)

    def hands_back(self, error: BaseException) -> bool:
        """Whether the job ``error`` ended is handed back rather than failed or canceled: any error once the stop
        is requested (a cancel asked by its client still cancels it: ``Jobs.hand_back`` refuses such a job)."""
        return self.requested and isinstance(error, Exception)
