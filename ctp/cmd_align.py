"""``ctp align``: run one alignment in-process (the embedded default: no Redis, no server).

Exit codes: 0 success; 1 the run failed; 2 bad usage or invalid input (a refused mesh, an option out
of range); 3 the vision-language model is unavailable (missing weights offline); 130 interrupted.
Errors are one line on stderr (``error: CODE: message``); a progress bar goes to stderr and a one-line
JSON summary to stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

from ctp_core.config import MAX_ALTERNATIVES, Runtime
from ctp_core.errors import ConfigError, ImageError, MeshError
from ctp_core.priors import PROVIDERS
from ctp_core.reading import names
from ctp_core.reading.counts import CHOICES, MAX_COPIES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", type=Path, metavar="TARGET",
                        help="the anchor mesh (GLB, glTF-binary, OBJ zip, PLY, STL)")
    parser.add_argument("source", type=Path, metavar="SOURCE", help="the mesh to place")
    guide = parser.add_mutually_exclusive_group()
    guide.add_argument("--prompt", metavar="TEXT", help="text describing the arrangement")
    guide.add_argument("--image", type=Path, metavar="REF.png", help="reference picture (PNG/JPEG) instead of a prompt")
    add_run_arguments(parser)
    parser.add_argument("--target-name", metavar="NAME",
                        help="object name for the priors (default: from the file name)")
    parser.add_argument("--source-name", metavar="NAME",
                        help="object name for the priors (default: from the file name)")
    add_switch(parser, "--judge-up", "upright_judge", True,
               "let the guidance model pick the target's up from renders named --target-name (needs real weights)")
    parser.add_argument("--count", type=int, metavar="N",
                        help=f"place N copies of the source (1 to {MAX_COPIES}; default: the prompt's number, "
                             "\"three apples\", else 1); the GLB has one node per copy, SOURCE-NAME_1 ...")
    parser.add_argument("--arrangement", choices=CHOICES, default="auto",
                        help="how copies stand together: auto (the prompt's \"around\", \"in a row\", \"stack "
                             "of\", else scatter), scatter, around (facing the target), row, stack")
    parser.add_argument("--alternatives", type=int, default=1, metavar="N",
                        help="also write the next best distinct placements, up to N in all with the answer "
                             "(--out's name with -2, -3, ... before .glb; at most 4, as many as the run refined)")


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Outputs and run options shared by ``ctp align`` and ``ctp assemble``.

    A run option's flag is ``--<option>`` (``options.OPTION_PATHS``) or a switch setting it, with its type or
    choices from the ``AlignConfig`` field behind it; ``config_from_args`` nests the values the same way.
    """
    parser.add_argument("--out", type=Path, default=Path("scene.glb"), metavar="scene.glb",
                        help="output GLB (default scene.glb)")
    parser.add_argument("--report", type=Path, metavar="report.json", help="write the JSON report here")
    parser.add_argument("--preview", type=Path, metavar="preview.png", help="write a 4-view preview PNG here")
    add_option(parser, "preset", "NAME", "default (search, then a short refinement) | fast (the relation and the "
               "geometry choose, the guide glances) | descent | paper | test", default="default")
    add_option(parser, "model", "SPEC", "guidance model: auto (default: the default CLIP model where its weights are "
               "here, else none), hf:REPO_OR_PATH, open_clip:ARCH:TAG, onnx:DIR, random:ARCH (random weights: tests)")
    add_switch(parser, "--scale", "scale", True,
               "find the source's scale: from the priors' size ratio (or the geometry), searched and refined")
    add_option(parser, "restarts", "N")
    add_option(parser, "steps", "N", "total steps per restart over all phases")
    add_option(parser, "candidates", "N", "poses the search scores (default: the preset's)")
    add_switch(parser, "--no-search", "search", False,
               "no search: the optimiser starts from random poses (as the descent preset)")
    add_option(parser, "seed", "N")
    parser.add_argument("--device", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, metavar="N", help="torch CPU threads (and ONNX Runtime's)")
    parser.add_argument("--runtime", choices=get_args(Runtime),
                        help="where forward-only encoding runs (selection, judge): ONNX Runtime fp32 or int8, "
                        "torch, or auto (default; docs/guidance.md)")
    add_option(parser, "contact_ratio", "R", "soft-ICP ratio r in [0, 1] (default: prior)")
    add_option(parser, "penetration")
    add_option(parser, "size_ratio", "S", "source/target size in [0.01, 100] (scale mode)")
    add_option(parser, "hparams_provider", "NAME", f"{' | '.join(PROVIDERS)} (default {PROVIDERS[0]})")
    parser.add_argument("--selection-only", action="store_true",
                        help="the guide picks the best pose but gives no gradient (the default and fast presets "
                             "already do; descent and paper descend it)")
    add_switch(parser, "--no-guidance", "lambda_clip", 0.0, "geometry only (lambda_clip = 0)")
    add_switch(parser, "--keep-up", "upright", False,
               "keep the target file's +Y as up whatever its format or --target-up says")
    for role in ("target", "source"):
        add_option(parser, f"{role}_up", "DIR", f"the {role}'s up: file (default: +Y for glTF; OBJ, STL, PLY Y-up "
                   "unless it stands only with +Z up), auto (geometric guess), or +x, -x, +y, -y, +z, -z")
        add_option(parser, f"{role}_front", "DIR", f"the {role}'s front: file (default: +Z for glTF), auto, or an "
                   "axis at right angles to its up")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def add_option(parser: argparse.ArgumentParser, name: str, metavar: str | None = None, help: str | None = None,
               default: Any = None) -> None:
    """``--<name>`` for the run option ``name``: an int, a float, a string, or one of a Literal's choices."""
    from ctp_core.config.options import config_field

    kind = config_field(name).annotation
    if get_origin(kind) in (Union, UnionType):  # optional: X | None
        kind = next(a for a in get_args(kind) if a is not type(None))
    typed = ({"choices": get_args(kind)} if get_origin(kind) is Literal else
             {"type": kind} if kind in (int, float) else {})
    parser.add_argument(f"--{name.replace('_', '-')}", dest=name, metavar=metavar, help=help, default=default, **typed)


def add_switch(parser: argparse.ArgumentParser, flag: str, name: str, value: Any, help: str) -> None:
    """A flag without a value that sets the run option ``name`` to ``value``."""
    parser.add_argument(flag, dest=name, action="store_const", const=value, help=help)


def config_from_args(args: argparse.Namespace):
    """Preset + the flags the user gave (unset flags leave the preset's values)."""
    from ctp_core.config import AlignConfig
    from ctp_core.config.options import OPTION_PATHS, nest

    given = {name: getattr(args, name) for name in OPTION_PATHS if getattr(args, name, None) is not None}
    overrides = nest({name: value for name, value in given.items() if name != "preset"})
    overrides.update({k: v for k, v in {"device": args.device, "threads": args.threads, "runtime": args.runtime}.items()
                      if v is not None})
    if args.selection_only:
        overrides.setdefault("loss", {})["selection_only"] = True
    return AlignConfig.from_preset(given["preset"], **overrides)


class ProgressBar:
    """One redrawn line on a terminal; one line per phase event otherwise (logs stay readable).

    Beside the step count it shows what a person can follow, from the engine's readout of the restarts' best poses
    on the fixed evaluation views (``ProgressEvent``): ``holds``, in how many the prompt's relation holds (of
    the candidates scored, in the search); ``match``, the answer's cosine between its views and the prompt (or
    image) under the guidance model, higher is better; ``gap``, its distance to the target, % of the source's
    size, lower is better. The answer is the restart the run would answer with at that step
    (``ProgressEvent.restart``: ``ordering.select_answer``), the final one at the end. The objective itself is
    not shown: its weights change between phases, so its value jumps although nothing got worse.
    """

    LEGEND = ("progress: holds = where the prompt's relation holds; match = cosine between the answer's "
              "views and the prompt (higher is better); gap = its distance to the target, % of the source's size")

    def __init__(self, stream=None, enabled: bool = True):
        # sys.stderr as it is when a run starts, not when this module was imported (a test's capture may be gone)
        self.stream, self.enabled = stream if stream is not None else sys.stderr, enabled
        self.tty = self.stream.isatty()
        self._legend = False
        self._readout = ""

    def __call__(self, event) -> None:
        self._readout = readout(event) or self._readout  # a phase start carries none: show the last
        if not self.enabled or (not self.tty and event.kind == "step"):
            return
        if not self._legend:
            self.stream.write(self.LEGEND + "\n")
            self._legend = True
        width = 20
        filled = int(event.fraction * width)
        eta = f"{event.eta_s:4.0f}s" if event.eta_s is not None else "   ?"
        where = (f"search {event.step}/{event.steps} candidates" if event.stage == "search" else
                 f"phase {event.phase}/{event.phases} step {event.step}/{event.steps}")
        line = f"[{'#' * filled}{'.' * (width - filled)}] {where} eta {eta}{self._readout}"
        if self.tty:
            self.stream.write("\r" + line + "\033[K" + ("\n" if event.kind == "done" else ""))
        else:
            self.stream.write(f"{event.kind}: {line}\n")
        self.stream.flush()


def readout(event) -> str:
    """`` holds H/N match M gap G%`` from an event's readout (each part only where the event has it)."""
    out = ""
    if event.relation_holds is not None and event.relation_checked:
        out += f" holds {event.relation_holds}/{event.relation_checked}"
    if event.guide_match is not None:
        out += f" match {event.guide_match:.3f}"
    if event.contact_gap is not None:
        out += f" gap {100 * event.contact_gap:.1f}%"
    return out


def check_inputs(args: argparse.Namespace) -> None:
    """Missing input files are reported at once, with their paths, before the engine's imports (seconds)."""
    for role, path, error in (("target", args.target, MeshError), ("source", args.source, MeshError),
                              ("image", args.image, ImageError)):
        if path is not None and not path.is_file():
            raise error(f"{role}: {'not a file' if path.exists() else 'no such file'}: {path}", field=role)


def run(args: argparse.Namespace) -> int:
    if not args.prompt and not args.image and args.lambda_clip is None:  # --no-guidance not given
        raise ConfigError("give --prompt TEXT or --image REF.png (or --no-guidance)", field="prompt")
    if not 1 <= args.alternatives <= MAX_ALTERNATIVES:
        raise ConfigError(f"--alternatives must be 1 to {MAX_ALTERNATIVES}", field="alternatives")
    check_inputs(args)
    config = config_from_args(args)
    from ctp_core.reading.counts import choose

    target_name = args.target_name or names.default_name(args.target.name, "target")
    source_name = args.source_name or names.default_name(args.source.name, "source")
    count, arrangement, _ = choose(args.prompt, args.count, args.arrangement, source_name)
    if count > 1 and (args.image is not None or args.alternatives > 1):
        raise ConfigError("several copies are guided by a prompt, with one placement each: no --image or "
                          "--alternatives", field="count")
    target, source = load_meshes([(args.target, "target"), (args.source, "source")])
    from ctp_core import export, io
    from ctp_core.align import align
    from ctp_core.config import AUTO
    from ctp_core.guide.selection import NONE, pull_command

    if count > 1:
        return _run_copies(args, target, source, config, count, arrangement, target_name, source_name)
    image = io.load_image(args.image) if args.image else None
    started = time.perf_counter()
    result = align(target, source, args.prompt, config, image=image, target_name=target_name,
                   source_name=source_name, on_event=ProgressBar(enabled=not args.quiet))
    export.write_outputs(result, glb=args.out, report_path=args.report, preview=args.preview)
    others = []
    for k in range(1, min(args.alternatives, len(result.alternatives))):
        path = args.out.with_name(f"{args.out.stem}-{k + 1}{args.out.suffix}")
        path.write_bytes(export.scene_glb(result.alternative(k)))
        others.append(str(path))
    for warning in result.warnings:  # one line each, whatever --quiet says (the report has them too)
        print(f"warning: {warning['code']}: {warning['message']}", file=sys.stderr)
    if result.guide == NONE and config.model == AUTO and config.uses_model:  # auto found no model: say so, once
        print(f"note: no guide: {result.guide_why.removeprefix('auto: ')}; `{pull_command()}` gets the model",
              file=sys.stderr)
    placed = said(result)
    if not args.quiet:
        print(f"placed: {placed}", file=sys.stderr)
    summary = {"out": str(args.out), "said": placed, "objective": round(result.objective, 6),
               "scale": round(result.scale, 6),
               "translation": [round(v, 6) for v in result.translation.tolist()],
               "seconds": round(time.perf_counter() - started, 2), "preset": config.preset,
               "model": result.model, "guide": result.guide, "guide_why": result.guide_why, "runtime": result.runtime,
               "hparams": result.priors.get("provider"), "relation": result.relation,
               "names": {"target": result.priors["target_name"], "source": result.priors["source_name"]}}
    if others:
        summary["alternatives"] = others
    if result.scaling is not None:  # --scale: where the scale started and why (the report's extra.scale has all)
        summary["initial_scale"] = round(result.scaling["initial"], 6)
        summary["scale_from"] = (result.scaling["constraint"]["kind"] if result.scaling["from"] == "geometry"
                                 else f"priors: size ratio {result.scaling['size_ratio']:.3g}")
    print(json.dumps(summary))
    return 0


def load_meshes(files: list[tuple[Path, str]]) -> list:
    """The meshes of ``files`` ((path, the name errors give it) each), read by the bounded loader the service uses
    (``ctp_core.io.loader``). Its child process reads them while this one imports the engine (torch, trimesh:
    seconds), so on two cores the one wait hides the other. The loader closes first, so an interrupt waits on no
    load in flight."""
    from ctp_core.io.loader import MeshLoader

    with ThreadPoolExecutor(1) as pool, MeshLoader(1) as loader:
        meshes = pool.submit(lambda: [loader.load(path, name=name) for path, name in files])
        # the engine, imported meanwhile: the caller's own imports of it then cost nothing
        import ctp_core.align  # noqa: F401
        import ctp_core.export  # noqa: F401

        return meshes.result()


def said(result) -> str:
    """The answer in words a person reads (the JSON fields beside it are for machines): the relation's verdict,
    contact, and where the source went, turned and at what size (lengths in the files' units: metres for glTF)."""
    import numpy as np

    from ctp_core.metrics import rotation_error_deg

    relation = result.relation
    words = [f"'{relation['name']}' {'holds' if relation['holds'] else 'does not hold'}" if relation
             else "no relation read from the prompt"]
    if relation and relation.get("stable") is False:
        words.append("may tip over")
    if result.contact:
        words.append("touching" if result.contact["touching"]
                     else f"not touching: a gap of {100 * result.contact['gap']:.0f} % of the source's size")
    x, y, z = result.translation.tolist()
    words.append(f"moved to ({x:.3f}, {y:.3f}, {z:.3f}) in the target's file units (metres for glTF)")
    angle = rotation_error_deg(result.rotation, np.eye(3))
    words.append("not turned" if angle < 0.05 else f"turned {angle:.1f}°")
    scale = result.scale
    words.append("at its file's size" if abs(scale - 1) < 5e-4 else f"at {scale:.3f} times its file's size")
    return ", ".join(words)


def _run_copies(args: argparse.Namespace, target, source, config, count: int, arrangement: str, target_name: str,
                source_name: str) -> int:
    """``--count`` over 1 (or a prompt's number): the copies' GLB, report and preview; one line per copy on stderr."""
    from ctp_core import export
    from ctp_core.assembly.copies import place_copies

    bar = ProgressBar(enabled=not args.quiet)

    def on_copy(index: int, total: int) -> None:
        if not args.quiet:
            print(f"copy {index}/{total}", file=sys.stderr)

    started = time.perf_counter()
    copies = place_copies(target, source, args.prompt, config, count=count, arrangement=arrangement,
                          target_name=target_name, source_name=source_name, on_event=bar, on_copy=on_copy)
    export.write_outputs(copies, glb=args.out, report_path=args.report, preview=args.preview)
    summary = {"out": str(args.out), "count": copies.count, "arrangement": copies.arrangement,
               "relation": None if copies.reading is None else copies.reading.name,
               "seconds": round(time.perf_counter() - started, 2), "preset": config.preset,
               "guide": copies.guide, "guide_why": copies.guide_why, "metrics": copies.metrics,
               "copies": [{"name": c.name, "holds": None if c.relation is None else c.relation["holds"],
                           "seconds": c.seconds} for c in copies.copies],
               "names": {"target": target_name, "source": source_name}}
    print(json.dumps(summary))
    return 0
