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
from pathlib import Path

from ctp_core.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", type=Path, help="the anchor mesh (GLB, glTF-binary, OBJ zip, PLY, STL)")
    parser.add_argument("source", type=Path, help="the mesh to place")
    guide = parser.add_mutually_exclusive_group()
    guide.add_argument("--prompt", help="text describing the arrangement")
    guide.add_argument("--image", type=Path, help="reference picture (PNG/JPEG) instead of a prompt")
    parser.add_argument("--out", type=Path, default=Path("scene.glb"), help="output GLB (default scene.glb)")
    parser.add_argument("--report", type=Path, help="write the JSON report here")
    parser.add_argument("--preview", type=Path, help="write a 4-view preview PNG here")
    parser.add_argument("--preset", default="default",
                        help="default (search, then a short refinement) | descent | paper | test")
    parser.add_argument("--model", help="guidance model: hf:REPO_OR_PATH, open_clip:ARCH:TAG, random:ARCH")
    parser.add_argument("--scale", action="store_true", help="optimise isotropic scale too")
    parser.add_argument("--restarts", type=int)
    parser.add_argument("--steps", type=int, help="total steps per restart over all phases")
    parser.add_argument("--candidates", type=int, help="poses the search scores (default: the preset's)")
    parser.add_argument("--no-search", action="store_true",
                        help="no search: the optimiser starts from random poses (as the descent preset)")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--device", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, help="torch CPU threads")
    parser.add_argument("--contact-ratio", type=float, help="soft-ICP ratio r in [0, 1] (default: prior)")
    parser.add_argument("--penetration", choices=["auto", "allow", "forbid"])
    parser.add_argument("--size-ratio", type=float, help="source/target size in [0.01, 100] (scale mode)")
    parser.add_argument("--hparams-provider", help="rules | openai (default rules)")
    parser.add_argument("--target-name", help="object name for the priors (default: file stem)")
    parser.add_argument("--source-name", help="object name for the priors (default: file stem)")
    parser.add_argument("--selection-only", action="store_true",
                        help="reference-code behaviour: text picks the best pose but gives no gradient")
    parser.add_argument("--no-guidance", action="store_true", help="geometry only (lambda_clip = 0)")
    parser.add_argument("--keep-up", action="store_true",
                        help="keep the target file's +Y as up (no automatic upright turn of the target)")
    parser.add_argument("--judge-up", action="store_true",
                        help="let the guidance model pick the target's up from renders named --target-name "
                        "(needs real weights)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def config_from_args(args: argparse.Namespace):
    """Preset + the flags the user gave (unset flags leave the preset's values)."""
    from ctp_core.config import AlignConfig

    top = {"model": args.model, "scale": args.scale or None, "seed": args.seed, "device": args.device,
           "threads": args.threads, "contact_ratio": args.contact_ratio, "penetration": args.penetration,
           "size_ratio": args.size_ratio, "hparams_provider": args.hparams_provider}
    overrides = {k: v for k, v in top.items() if v is not None}
    if args.keep_up:
        overrides["upright"] = False
    if args.judge_up:
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
    """One redrawn line on a terminal; one line per phase event otherwise (logs stay readable)."""

    def __init__(self, stream=sys.stderr, enabled: bool = True):
        self.stream, self.enabled = stream, enabled
        self.tty = stream.isatty()

    def __call__(self, event) -> None:
        if not self.enabled or (not self.tty and event.kind == "step"):
            return
        width = 30
        filled = int(event.fraction * width)
        eta = f"{event.eta_s:5.0f}s" if event.eta_s is not None else "    ?"
        best = f" best {event.best_objective:.4f}" if event.best_objective is not None else ""
        where = (f"search {event.step}/{event.steps} candidates" if event.stage == "search" else
                 f"phase {event.phase}/{event.phases} step {event.step}/{event.steps}")
        line = f"[{'#' * filled}{'.' * (width - filled)}] {where} eta {eta}{best}"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if event.kind == "done" else ""))
        else:
            self.stream.write(f"{event.kind}: {line}\n")
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    from ctp_core import export, io
    from ctp_core.align import align

    if not args.prompt and not args.image and not args.no_guidance:
        raise ConfigError("give --prompt TEXT or --image REF.png (or --no-guidance)", field="prompt")
    config = config_from_args(args)
    target = io.load_mesh(args.target, name="target")
    source = io.load_mesh(args.source, name="source")
    image = _read_image(args.image) if args.image else None
    started = time.perf_counter()
    result = align(target, source, args.prompt, config, image=image,
                   target_name=args.target_name or args.target.stem,
                   source_name=args.source_name or args.source.stem,
                   on_event=ProgressBar(enabled=not args.quiet))
    export.write_outputs(result, glb=args.out, report_path=args.report, preview=args.preview)
    summary = {"out": str(args.out), "objective": round(result.objective, 6), "scale": round(result.scale, 6),
               "translation": [round(v, 6) for v in result.translation.tolist()],
               "seconds": round(time.perf_counter() - started, 2), "preset": config.preset,
               "model": result.extra.get("model"), "hparams": result.hparams.get("source")}
    print(json.dumps(summary))
    return 0


def _read_image(path: Path):
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            return np.asarray(img.convert("RGB"))
    except (OSError, UnidentifiedImageError) as exc:
        raise ConfigError(f"cannot read image {path}: {exc}", field="image") from None

