"""Fault points for the fault tests: a crash at an exact instant that no signal sent from outside could hit.

``point(name)`` SIGKILLs this process where the environment variable ``CTP_TEST_KILL_AT`` names that point (the
tests set it on an API they start); unset, as in every deployment, it does nothing. The points are the seams a
crash must not turn into a lost or doubled job: ``submit.stored`` (a submit's uploads stored, its record not yet
written) and ``submit.queued`` (the job queued, the client not yet answered).
"""

from __future__ import annotations

import os
import signal

VARIABLE = "CTP_TEST_KILL_AT"


def point(name: str) -> None:
    """Die here, at once and without clean-up, if this is the point the environment names."""
    if os.environ.get(VARIABLE) == name:
        os.kill(os.getpid(), signal.SIGKILL)
