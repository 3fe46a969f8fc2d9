"""The worker's stop (``worker.stop``): the one rule for what a job's error means once a stop is requested, and a stop
signal during start-up that is never lost."""

from __future__ import annotations

import os
import signal
import time

from ctp_core.errors import Canceled
from ctp_core.io.loader import LoaderUnavailable
from worker.stop import Stop


def test_once_a_stop_is_requested_any_error_hands_the_job_back():
    stop = Stop()
    assert not stop.hands_back(LoaderUnavailable("the service is shutting down"))  # no stop: the job's own
    assert stop.request(signal.SIGINT) and not stop.request(signal.SIGTERM)  # the first signal counts
    assert stop.exit_status == 128 + signal.SIGINT
    for error in (LoaderUnavailable("the service is shutting down"), Canceled("the run was cancelled"),
                  OSError("an upload cut short"), RuntimeError("an encoder session closed")):
        assert stop.hands_back(error), error
    assert not stop.hands_back(SystemExit(1))  # the worker leaving (Redis gone for good) is no job's error


def test_a_stop_signal_while_starting_is_kept_when_its_exit_is_swallowed():
    """Some imports catch every exception, the stop's exit included: the mark stays, and the handlers in place
    before are put back after."""
    before = signal.getsignal(signal.SIGTERM)
    stop = Stop()
    with stop.listening():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)  # the handler runs here, at the latest
        except BaseException:  # noqa: BLE001 - what such an import does
            pass
        assert stop.requested and stop.exit_status == 128 + signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is before
