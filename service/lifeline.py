"""A lifeline: the processes ``ctp serve`` starts (its workers, the keeper of its embedded Redis) end with it, however
it ends, SIGKILL included.

The parent makes one pipe and keeps its write end open, never writing, for its whole life; each child inherits the
read end (``child_end``, passed with ``pass_fds``). When the parent is gone, by exit or by any signal, the kernel
closes the write end and the read end reads end of file: the child ``watch``es for that. Unlike a parent-death signal
(``PR_SET_PDEATHSIG``), which the kernel sends when the *thread* that started the child ends, the pipe lasts as long
as the process, so a child started by ``ctp serve``'s supervisor thread is not stopped when that thread is.

The write end is not inheritable (``os.pipe``): a child that exec's does not hold it, so nothing but the parent keeps
the pipe open.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable

_ends: tuple[int, int] | None = None  # this process's lifeline, read and write ends, made on first use


def child_end() -> int:
    """The read end of this process's lifeline, to be passed to a child (``pass_fds``); it reads end of file once
    this process is gone."""
    global _ends
    if _ends is None:
        _ends = os.pipe()
    return _ends[0]


def watch(fd: int, on_end: Callable[[], None]) -> None:
    """Call ``on_end`` (in a daemon thread) once the lifeline ``fd``, inherited from the parent, reads end of file:
    the parent is gone."""
    def wait() -> None:
        while os.read(fd, 1):  # nothing is ever written: only the end is news
            pass
        on_end()

    threading.Thread(target=wait, name="ctp-lifeline", daemon=True).start()
