"""``ctp align``: run one alignment in-process (the embedded default: no Redis, no server).

Exit codes: 0 success; 1 the run failed; 2 bad usage or invalid input (a refused mesh, an option out
of range); 3 the vision-language model is unavailable (missing weights offline); 130 interrupted.
Errors are one line on stderr (``error: CODE: message``); a progress bar goes to stderr and a one-line
JSON summary to stdout.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import get_args

from ctp_core.config import Penetration, Runtime
from ctp_core.errors import ConfigError, ImageError, MeshError


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
    parser.add_argument("--judge-up", action="store_true",
                        help="let the guidance model pick the target's up from renders named --target-name "
                        "(needs real weights)")


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Outputs and run options shared by ``ctp align`` and ``ctp assemble``."""
    parser.add_argument("--out", type=Path, default=Path("scene.glb"), metavar="scene.glb",
                        help="output GLB (default scene.glb)")
    parser.add_argument("--report", type=Path, metavar="report.json", help="write the JSON report here")
    parser.add_argument("--preview", type=Path, metavar="preview.png", help="write a 4-view preview PNG here")
    parser.add_argument("--preset", default="default", metavar="NAME",
                        help="default (search, then a short refinement) | descent | paper | test")
    parser.add_argument("--model", metavar="SPEC",
                        help="guidance model: hf:REPO_OR_PATH, open_clip:ARCH:TAG, random:ARCH")
    parser.add_argument("--scale", action="store_true", help="optimise isotropic scale too")
    parser.add_argument("--restarts", type=int, metavar="N")
    parser.add_argument("--steps", type=int, metavar="N", help="total steps per restart over all phases")
    parser.add_argument("--candidates", type=int, metavar="N", help="poses the search scores (default: the preset's)")
    parser.add_argument("--no-search", action="store_true",
                        help="no search: the optimiser starts from random poses (as the descent preset)")
    parser.add_argument("--seed", type=int, metavar="N")
    parser.add_argument("--device", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, metavar="N", help="torch CPU threads (and ONNX Runtime's)")
    parser.add_argument("--runtime", choices=get_args(Runtime),
                        help="where forward-only encoding runs (selection, judge): ONNX Runtime fp32 or int8, "
                        "torch, or auto (default; README)")
    parser.add_argument("--contact-ratio", type=float, metavar="R", help="soft-ICP ratio r in [0, 1] (default: prior)")
    parser.add_argument("--penetration", choices=get_args(Penetration))
    parser.add_argument("--size-ratio", type=float, metavar="S", help="source/target size in [0.01, 100] (scale mode)")
    parser.add_argument("--hparams-provider", metavar="NAME", help="rules | openai (default rules)")
    parser.add_argument("--selection-only", action="store_true",
                        help="reference-code behaviour: text picks the best pose but gives no gradient")
    parser.add_argument("--no-guidance", action="store_true", help="geometry only (lambda_clip = 0)")
    parser.add_argument("--keep-up", action="store_true",
                        help="keep the target file's +Y as up (no automatic upright turn of the target)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def config_from_args(args: argparse.Namespace):
    """Preset + the flags the user gave (unset flags leave the preset's values)."""
    from ctp_core.config import AlignConfig

    top = {"model": args.model, "scale": args.scale or None, "seed": args.seed, "device": args.device,
           "threads": args.threads, "runtime": args.runtime, "contact_ratio": args.contact_ratio,
           "penetration": args.penetration,
           "size_ratio": args.size_ratio, "hparams_provider": args.hparams_provider}
    overrides = {k: v for k, v in top.items() if v is not None}
    if args.keep_up:
        overrides["upright"] = False
    if getattr(args, "judge_up", False):
        overrides["upright_judge"] = True
    optim = {k: v for k, v in {"restarts": args.restarts, "steps": args.steps}.items() if v is not None}
    loss = {}
    if args.selection_only:
        loss["selection_only"] = True
    if args.no_guidance:
        loss["lambda_clip"] = 0.0
    if optim:
        overrides["optim"] = optim
    search = {k: v for k, v in {"candidates": args.candidates, "enabled": False if args.no_search else None}.items()
              if v is not None}
    if search:
        overrides["search"] = search
    if loss:
        overrides["loss"] = loss
    return AlignConfig.from_preset(args.preset, **overrides)


class ProgressBar:
    """One redrawn line on a terminal; one line per phase event otherwise (logs stay readable).

    Beside the step count it shows what a person can follow, from the last step's losses (means over the
    restarts): ``match``, the cosine between the rendered views and the prompt (or image) under the
    guidance model, higher is better; ``gap``, the contact distance between the objects (the root of the
    soft-ICP term, in % of the target's size), lower is better. The objective itself is not shown: its
    weights change between phases, so its value jumps although nothing got worse.
    """

    LEGEND = ("progress: match = cosine between the views and the prompt (higher is better); "
              "gap = distance between the touching parts, % of the target's size (lower is better)")

    def __init__(self, stream=sys.stderr, enabled: bool = True):
        self.stream, self.enabled = stream, enabled
        self.tty = stream.isatty()
        self._legend = False
        self._losses: dict[str, float] = {}

    def __call__(self, event) -> None:
        self._losses = event.losses or self._losses  # phase events carry none: show the last step's
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
        line = f"[{'#' * filled}{'.' * (width - filled)}] {where} eta {eta}{figures(self._losses)}"
        if self.tty:
            self.stream.write("\r" + line + "\033[K" + ("\n" if event.kind == "done" else ""))
        else:
            self.stream.write(f"{event.kind}: {line}\n")
        self.stream.flush()


def figures(losses: dict[str, float]) -> str:
    """`` match M gap G%`` from a step's losses (each part only when its term ran)."""
    out = ""
    if losses.get("clip"):  # L_clip = -cosine; absent (or 0) when the guidance is off
        out += f" match {-losses['clip']:.3f}"
    if "icp" in losses:  # soft-ICP: mean squared distance in the normalised frame (target longest side 2)
        out += f" gap {100 * math.sqrt(max(losses['icp'], 0.0)) / 2:.1f}%"
    return out


def check_inputs(args: argparse.Namespace) -> None:
    """Missing input files are reported at once, with their paths, before the engine's imports (seconds)."""
    for role, path, error in (("target", args.target, MeshError), ("source", args.source, MeshError),
                              ("image", args.image, ImageError)):
        if path is not None and not path.is_file():
            raise error(f"{role}: {'not a file' if path.exists() else 'no such file'}: {path}", field=role)


def run(args: argparse.Namespace) -> int:
    if not args.prompt and not args.image and not args.no_guidance:
        raise ConfigError("give --prompt TEXT or --image REF.png (or --no-guidance)", field="prompt")
    check_inputs(args)
    config = config_from_args(args)
    from ctp_core import export, io  # the engine (torch, trimesh): seconds to import
    from ctp_core.align import align
    from ctp_core.loader import MeshLoader

    with MeshLoader(1) as loader:  # the same bounded loading as the service (ctp_core.loader)
        target = loader.load(args.target, name="target")
        source = loader.load(args.source, name="source")
    image = io.load_image(args.image) if args.image else None
    started = time.perf_counter()
    result = align(target, source, args.prompt, config, image=image,
                   target_name=args.target_name or io.default_name(args.target.name, "target"),
                   source_name=args.source_name or io.default_name(args.source.name, "source"),
                   on_event=ProgressBar(enabled=not args.quiet))
    export.write_outputs(result, glb=args.out, report_path=args.report, preview=args.preview)
    summary = {"out": str(args.out), "objective": round(result.objective, 6), "scale": round(result.scale, 6),
               "translation": [round(v, 6) for v in result.translation.tolist()],
               "seconds": round(time.perf_counter() - started, 2), "preset": config.preset,
               "model": result.model, "runtime": result.runtime,
               "hparams": result.priors.get("provider"),
               "names": {"target": result.priors["target_name"], "source": result.priors["source_name"]}}
    print(json.dumps(summary))
    return 0
