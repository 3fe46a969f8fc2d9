"""``ctp mcp``: ctp's placements as Model Context Protocol tools for language-model agents (``ctp.mcp_server``).

Over stdio by default (a desktop client starts it as a child process); ``--http`` serves streamable HTTP on
``--host``/``--port`` instead (loopback by default), at the path ``/mcp``. It is a client of the HTTP service:
``--service`` (or ``CTP_SERVICE_URL``, default the address ``make serve`` listens on) with ``--api-key`` (or
``CTP_SERVICE_API_KEY``) where the service has API keys; the tools read mesh files on this machine and keep each
job's result.glb and report.json under ``--results``. docs/mcp.md: configuring a client, the tools, an example.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

DEFAULT_SERVICE = "http://127.0.0.1:8000"  # `make serve`


def _results_default() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ctp" / "mcp"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--service", metavar="URL", default=os.environ.get("CTP_SERVICE_URL", DEFAULT_SERVICE),
                        help="the ctp HTTP service the tools use (default: $CTP_SERVICE_URL, else %(default)s)")
    parser.add_argument("--api-key", metavar="KEY", default=os.environ.get("CTP_SERVICE_API_KEY"),
                        help="API key for the service (default: $CTP_SERVICE_API_KEY)")
    parser.add_argument("--results", metavar="DIR", type=Path, default=None,
                        help="folder for each job's result.glb and report.json (default: "
                        "$XDG_CACHE_HOME/ctp/mcp, else ~/.cache/ctp/mcp)")
    parser.add_argument("--http", action="store_true", help="serve streamable HTTP at /mcp instead of stdio")
    parser.add_argument("--host", default="127.0.0.1", help="with --http: interface to listen on (default: "
                        "%(default)s)")
    parser.add_argument("--port", type=int, default=8765, help="with --http: TCP port (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from ctp.mcp_server import Service, build

    service = Service(args.service.rstrip("/"), args.api_key or None, args.results or _results_default())
    app = build(service)
    if args.http:
        app.run("streamable-http", host=args.host, port=args.port)
    else:
        app.run()
    return 0
