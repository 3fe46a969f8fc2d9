"""The worker's stop: one flag, set by the first SIGINT or SIGTERM before any part of the worker is torn down, and
the one rule for what an error that ends a job means once it is set.

Once a stop is requested, a running job that ends with an error is handed back (queued again, its attempt not
counted, ``Jobs.hand_back``) instead of failed: the error may be the stop's own doing (the optimiser told to stop
at its next step, a loading process or an encoder session closing under the job, an upload to the store cut
short), and nothing but a run elsewhere tells that from the job's own fault, which then fails it there. A job
that ends without an error while the stop is under way has simply finished first.
"""

from __future__ import annotations

import threading


class Stop:
    """Whether this worker is stopping (``request``: the signal handler), and what that makes of a job's error."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def request(self) -> bool:
        """Mark the worker stopping; True the first time (a later signal changes nothing)."""
        first = not self._event.is_set()
        self._event.set()
        return first

    @property
    def requested(self) -> bool:
        return self._event.is_set()

    def hands_back(self, error: BaseException) -> bool:
        """Whether the job ``error`` ended is handed back rather than failed or canceled: any error once the stop
        is requested (a cancel asked by its client still cancels it: ``Jobs.hand_back`` refuses such a job)."""
        return self.requested and isinstance(error, Exception)
