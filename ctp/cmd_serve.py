"""``ctp serve`` (the HTTP API) and ``ctp worker`` (a queue worker).

``ctp serve`` with no ``REDIS_URL`` is the one-command service: it starts an embedded redis-server
(``service.embedded``) and one worker process next to the API, restarts either when it dies
(``service.supervisor``), and stops them on exit. Killed outright (SIGKILL, the out-of-memory killer), it takes
them along: each holds its lifeline (``service.lifeline``), the workers hand their running jobs back and leave, and
the embedded Redis stops after them. With ``REDIS_URL`` it serves the API only and workers are started elsewhere with
``ctp worker``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time

STOP_GRACE_S = 10.0
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def add_arguments(parser: argparse.ArgumentParser, name: str) -> None:
    if name == "serve":
        parser.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: %(default)s)")
        parser.add_argument("--port", type=int, default=8000, help="TCP port (default: %(default)s)")
        parser.add_argument("--workers", type=int, default=None,
                            help="worker processes to start here (default: 1 with the embedded Redis, "
                            "0 with REDIS_URL)")
    else:
        parser.add_argument("--burst", action="store_true", help="quit once the queue is empty")
        parser.add_argument("--name", default=None, help="worker name (default: HOST.PID)")
        parser.add_argument("--lifeline", type=int, default=None, metavar="FD",
                            help="an inherited pipe's read end whose write end the starting process holds (`ctp "
                            "serve` passes one): when that process is gone, however it ended, the worker stops as on "
                            f"SIGTERM (its job handed back), and is killed if still there {STOP_GRACE_S:.0f} s later")


def run(args: argparse.Namespace) -> int:
    listening = contextlib.nullcontext()
    if args.command == "worker":  # before the imports below, which take seconds: a stop meanwhile is not lost
        from worker.stop import Stop

        listening = Stop().listening()
    with listening as stop:
        if args.command == "worker" and args.lifeline is not None and not _follow(args.lifeline):
            print(f"error: invalid_argument: --lifeline {args.lifeline} is not an open file descriptor",
                  file=sys.stderr)
            return 2
        from service.settings import Settings

        try:
            settings = Settings()
        except ValueError as exc:  # pydantic's ValidationError
            print(f"error: invalid_setting: {exc}", file=sys.stderr)
            return 2
        return _serve(settings, args) if args.command == "serve" else _work(settings, args, stop)


def _follow(fd: int) -> bool:
    """Stop this worker as SIGTERM does once its parent is gone (the lifeline ``fd`` ends), and kill it if it has not
    left ``STOP_GRACE_S`` later, as the parent's own stop would (``stop_processes``); False if ``fd`` is not open."""
    from service import lifeline

    try:
        os.fstat(fd)
    except OSError:
        return False

    def orphaned() -> None:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(STOP_GRACE_S)
        os.kill(os.getpid(), signal.SIGKILL)

    lifeline.watch(fd, orphaned)
    return True


def _work(settings, args: argparse.Namespace, stop) -> int:
    from worker.main import run_worker

    if not settings.redis_url:
        print("error: missing_setting: set REDIS_URL to the Redis shared with the API", file=sys.stderr)
        return 2
    return run_worker(settings, stop, burst=args.burst, name=args.name)


def _serve(settings, args: argparse.Namespace) -> int:
    import uvicorn

    from service import lifeline
    from service.app import create_app
    from service.embedded import EmbeddedRedis
    from service.supervisor import Supervisor

    embedded = None
    if not settings.redis_url:
        embedded = EmbeddedRedis(settings.redis_dir, detached=True)
        try:
            settings = settings.model_copy(update={"redis_url": embedded.start()})
        except RuntimeError as exc:  # a second `make serve`, or redis-server failed: one line, no traceback
            print(f"error: redis_unavailable: {exc}", file=sys.stderr)
            return 1
    n_workers = args.workers if args.workers is not None else (1 if embedded else 0)
    if n_workers:
        _say_if_default_model_missing(settings.model)
    env = {**os.environ, "REDIS_URL": settings.redis_url}
    fd = lifeline.child_end()  # the workers end with this process, however it ends (service.lifeline)
    # workers and the embedded Redis are restarted when they die (service.supervisor)
    supervisor = Supervisor(lambda: subprocess.Popen([sys.executable, "-m", "ctp", "worker", "--lifeline", str(fd)],
                                                     env=env, pass_fds=(fd,)), n_workers, embedded)
    where = f"embedded Redis in {embedded.data_dir}" if embedded else "REDIS_URL"
    print(f"ctp: serving on http://{args.host}:{args.port} ({where}, {n_workers} local worker(s))", file=sys.stderr)
    # uvicorn re-raises the SIGINT or SIGTERM it shut down on; make that an exception (exit status 128 + signal, no
    # traceback) so the children are stopped. Stopping drains: the API stops taking requests, the workers hand back
    # or finish their jobs, the embedded Redis stops last (it is detached from the terminal's Ctrl-C,
    # service.embedded). A closed terminal (SIGHUP) stops the same way.
    for stop in STOP_SIGNALS:
        signal.signal(stop, _exit_on_signal)
    try:
        app = create_app(settings)
        supervisor.start()
        uvicorn.run(app, host=args.host, port=args.port, log_level=settings.log_level.lower(),
                    timeout_graceful_shutdown=STOP_GRACE_S)
    finally:
        for stop in STOP_SIGNALS:  # a second Ctrl-C must not cut the drain short: it is bounded by the graces
            signal.signal(stop, signal.SIG_IGN)
        stop_processes(supervisor.stop())
        if embedded:
            embedded.stop()
    return 0


def _say_if_default_model_missing(spec: str) -> None:
    """One line at start when the local workers will not have the default model (``ctp_core.guide.checkpoints``); under
    auto, that jobs run without a guide and the command that gets the model (``ctp_core.guide.selection``)."""
    from ctp_core.config import AUTO
    from ctp_core.guide.checkpoints import looks_local, missing
    from ctp_core.guide.selection import NONE, choose, pull_command

    if spec == AUTO:
        choice = choose()
        if choice.guide == NONE:
            print(f"ctp: jobs run without a guide: {choice.why.removeprefix('auto: ')}; `{choice.get_model}` gets "
                  "the model (each next job uses it)", file=sys.stderr)
        return
    reason = missing(spec)
    if reason:
        hub = spec.startswith("hf:") and not looks_local(spec.removeprefix("hf:"))
        get = f"`{pull_command(spec)}` gets it (or CTP_ALLOW_DOWNLOAD=1)" if hub else "provide its weights"
        print(f"ctp: the default model {spec} cannot run here ({reason.split('. ')[0]}), so jobs that need it are "
              f"refused (503 model_unavailable); {get}, or start with CTP_MODEL=auto to run jobs without a guide",
              file=sys.stderr)


def _exit_on_signal(signum, _frame) -> None:
    raise SystemExit(128 + signum)


def stop_processes(processes: list[subprocess.Popen], grace_s: float = STOP_GRACE_S) -> None:
    """SIGTERM (a worker hands its job back, ``worker.main``; ``ctp serve``: stop its children), then SIGKILL after
    ``grace_s``; a job killed that way is reaped by the next API reaper (queued again once)."""
    for p in processes:
        p.terminate()
    for p in processes:
        try:
            p.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
