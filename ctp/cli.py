"""``ctp`` entry point: one sub-command per module, imported lazily so ``ctp --help`` stays fast.

Exit codes (all sub-commands): 0 success, 1 run failed, 2 bad usage or input (a refused mesh, an option
out of range), 3 the vision-language model is unavailable, 130 interrupted. Typed engine errors are
printed here, once for every sub-command, as one line ``error: CODE: message``; never a traceback. Nor for a
run out of memory (an allocation failed: ``job_too_large``, exit 1).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ctp_core.errors import ConfigError, CtpError, ImageError, JobTooLarge, MeshError, ModelError, forget, out_of_memory

EXIT_FAILED, EXIT_INPUT, EXIT_MODEL = 1, 2, 3

# name -> (module, help). Each module defines ``add_arguments(parser)`` and ``run(args) -> int``.
COMMANDS: dict[str, tuple[str, str]] = {
    "align": ("ctp.cmd_align", "place SOURCE relative to TARGET from a text prompt (in-process)"),
    "example": ("ctp.cmd_example", "write a generated sample pair (target and source GLB) to try ctp on"),
    "assemble": ("ctp.cmd_assemble", "build a scene one object at a time: BASE --add SOURCE PROMPT ... or --plan"),
    "compose": ("ctp.cmd_compose", "a scene from one sentence: OBJECTS... --prompt TEXT, read into a plan and placed"),
    "priors": ("ctp.cmd_priors", "print the scene priors (size ratio, penetration, contact ratio)"),
    "bench": ("ctp.cmd_bench", "run the evaluation harness over benchmark cases"),
    "models": ("ctp.cmd_models", "list, pull (resumable, verified) and remove guidance models in the local cache"),
    "serve": ("ctp.cmd_serve", "start the HTTP API (embedded Redis + worker when REDIS_URL is unset)"),
    "worker": ("ctp.cmd_serve", "run a queue worker against REDIS_URL"),
    "mcp": ("ctp.cmd_mcp", "serve ctp's placements as MCP tools for agents (stdio, or --http), over the service"),
}
# A command's deprecated spellings -> the command: still accepted and listed by ``ctp --help``, not in the synopsis.
ALIASES: dict[str, str] = {"hparams": "priors"}


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # shared CPU workers: no OpenMP spin-waiting
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="ctp", description="Copy-Transform-Paste: text-guided 3D alignment")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, add_help=False)
        for alias in (a for a, command in ALIASES.items() if command == name):
            sub.add_parser(alias, help=f"deprecated alias of {name}", add_help=False)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in (*COMMANDS, *ALIASES):
        if argv and argv[0] not in ("-h", "--help"):
            parser.print_usage(sys.stderr)
            print(f"ctp: error: unknown command {argv[0]!r}", file=sys.stderr)
            return 2
        parser.print_help()
        return 0 if argv else 2
    name = argv[0]
    module, cmd_parser = command_parser(name)
    try:
        args = cmd_parser.parse_args(argv[1:])
    except UsageError as exc:
        print(f"error: usage: {exc}", file=sys.stderr)
        return EXIT_INPUT
    args.command = name
    try:
        return int(module.run(args) or 0)
    except CtpError as exc:
        print(f"error: {exc.code}: {exc.message}", file=sys.stderr)
        return exit_code(exc)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if not out_of_memory(exc):
            raise
        forget(exc)
        too_large = JobTooLarge.of(exc)  # an allocation failed (a ulimit, the machine): one line, no traceback
        print(f"error: {too_large.code}: {too_large.message}", file=sys.stderr)
        return exit_code(too_large)


class UsageError(Exception):
    """Bad command-line usage, reported as one line like every other error (argparse prints two)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UsageError(f"{self.prog}: {message} (see {self.prog} --help)")


def command_parser(name: str, width: int | None = None) -> tuple[object, argparse.ArgumentParser]:
    """The sub-command's module and its argument parser (``width``: a fixed usage width); ``name`` may be an alias."""
    command = ALIASES.get(name, name)
    module_name, description = COMMANDS[command]
    module = importlib.import_module(module_name)
    if command != name:
        description = f"deprecated alias of {command}: {description}"
    formatter = argparse.HelpFormatter if width is None else (lambda prog: argparse.HelpFormatter(prog, width=width))
    parser = _Parser(prog=f"ctp {name}", description=description, formatter_class=formatter)
    module.add_arguments(parser, name) if _takes_name(module) else module.add_arguments(parser)
    return module, parser


def synopsis(width: int = 112) -> str:
    """Every sub-command's usage line, generated from its parser: docs/cli.md's synopsis is exactly this (a
    test compares them; print it with ``python -c "from ctp.cli import synopsis; print(synopsis())"``)."""
    prefix = len("usage: ")  # argparse's continuation lines are indented past it
    usages = (command_parser(name, width)[1].format_usage().rstrip().splitlines() for name in COMMANDS)
    return "\n".join(line[prefix:] for usage in usages for line in usage)


def exit_code(exc: CtpError) -> int:
    """The documented exit code of a typed engine error."""
    if isinstance(exc, (MeshError, ImageError, ConfigError)):
        return EXIT_INPUT
    return EXIT_MODEL if isinstance(exc, ModelError) else EXIT_FAILED


def _takes_name(module) -> bool:
    return module.add_arguments.__code__.co_argcount == 2


if __name__ == "__main__":
    sys.exit(main())
