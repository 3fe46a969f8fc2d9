"""``ctp assemble``: build a scene one object at a time, in-process (``ctp_core.assembly.assemble``).

    ctp assemble BASE --add SOURCE "PROMPT" [--add SOURCE "PROMPT" ...]
    ctp assemble --plan plan.yaml

Each ``--add`` places one object relative to the one added before it, or to the two placed objects a "between"
prompt names ("a lamp between the sofa and the armchair"); names come from the file names: ``coffee_cup.glb`` is
"coffee cup". A
plan file says more (paths are relative to the plan file)::

    base: table.glb              # the object that stays put; its file frame is the scene frame
    name: table                  # optional; default from the file name
    options: {seed: 1}           # optional: run options for every stage (the API's option names,
                                 # over the command's flags; preset and model come from --preset, --model)
    steps:
      - file: plate.glb
        prompt: a plate on the table
        name: plate              # optional; default from the file name; names must be unique
        on: table                # optional: the placed object it relates to; default the last placed
      - file: cup.glb
        image: cup_on_plate.png  # a reference picture instead of a prompt
        options: {contact_ratio: 0.3}   # this stage only
      - file: vase.glb
        prompt: a vase between the plate and the cup
        on: [plate, cup]         # two grounds ("between"); a between prompt naming placed objects finds them

Outputs, progress bar and exit codes are those of ``ctp align``: the GLB holds every object as its own
named node, the report every stage, the preview the whole scene.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from ctp.cmd_align import ProgressBar, add_run_arguments, config_from_args, load_meshes
from ctp_core.errors import ConfigError
from ctp_core.reading import names

_PLAN_KEYS = {"base", "name", "options", "steps"}
_ASSEMBLY_FLAGS = "--preset, --model"  # where preset and model are set (not in a plan's options)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = __doc__.split("\n\n", 2)[2]  # the plan format above
    parser.add_argument("base", type=Path, nargs="?", help="the object that stays put (not with --plan)")
    parser.add_argument("--add", nargs=2, action="append", metavar=("SOURCE", "PROMPT"), default=[],
                        help="place SOURCE as PROMPT says, relative to the object added before it (repeatable)")
    parser.add_argument("--plan", type=Path, help="a YAML plan (base, steps: file, prompt or image, name, on, "
                        "options; the format is below)")
    add_run_arguments(parser)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    if args.plan is not None:
        if args.base is not None or args.add:
            raise ConfigError("give either --plan or BASE with --add, not both", field="plan")
        base, base_name, steps, config = read_plan(args.plan, config)
    else:
        if args.base is None or not args.add:
            raise ConfigError("give BASE and at least one --add SOURCE PROMPT (or --plan plan.yaml)", field="add")
        entries = [{"file": str(path), "prompt": prompt} for path, prompt in args.add]
        base, steps = _steps(entries, Path.cwd(), config, args.base)
        base_name = names.default_name(args.base.name, "base")
    return run_assembly(args, base, base_name, steps, config)


def run_assembly(args: argparse.Namespace, base, base_name: str, steps: list, config, **summary: Any) -> int:
    """Place ``steps`` around ``base`` with a progress bar and a line per stage, write the outputs and print the
    JSON summary (``summary``: more of it): what ``ctp assemble`` and ``ctp compose`` do once they have steps."""
    from ctp_core import export
    from ctp_core.assembly.assemble import assemble

    bar = ProgressBar(sys.stderr, enabled=not args.quiet)

    def on_step(index: int, count: int, step) -> None:
        if not args.quiet:
            what = step.prompt if step.prompt is not None else "(image-guided)"
            sys.stderr.write(f"stage {index}/{count}: {step.name}: {what}\n")
            sys.stderr.flush()

    started = time.perf_counter()
    assembly = assemble(base, steps, config, base_name=base_name, on_event=bar, on_step=on_step)
    export.write_outputs(assembly, glb=args.out, report_path=args.report, preview=args.preview)
    print(json.dumps({
        "out": str(args.out), "seconds": round(time.perf_counter() - started, 2), "preset": config.preset,
        "model": assembly.results[0].result.model, "guide": assembly.results[0].result.guide,
        "objects": [{"name": p.name, "scale": round(p.to_scene.scale, 6),
                     "translation": [round(v, 6) for v in p.to_scene.translation.tolist()]}
                    for p in assembly.objects],
        "said": said(assembly.whole), "objectives": [round(s.result.objective, 6) for s in assembly.results],
        **summary}))
    return 0


def said(whole: dict[str, Any] | None) -> str:
    """Every relation of the final scene in words a person reads ("toolbox on workbench: holds; stool right
    workbench: does not hold, 4.0 mm into workbench"); the JSON fields beside it are for machines."""
    lines = []
    for judged in (whole or {}).get("relations", []):
        words = [("holds" if judged["holds"] else "does not hold") if judged["relation"] else "no relation read"]
        if judged.get("below_floor_mm", 0.0) >= 0.5:
            words.append(f"{judged['below_floor_mm']} mm below the floor")
        if judged.get("penetration_mm", 0.0) >= 0.5 and judged.get("into"):
            words.append(f"{judged['penetration_mm']} mm into {judged['into']}")
        lines.append(f"{judged['name']} {judged['relation'] or 'by'} {' and '.join(judged['on'])}: {', '.join(words)}")
    return "; ".join(lines)


def read_plan(path: Path, config):
    """(base mesh, base name, steps, config with the plan's options) of a YAML plan; every refusal is a
    ConfigError naming the key."""
    import yaml

    from ctp_core.assembly.plan import step_options

    try:
        plan = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read the plan {path}: {exc.strerror}", field="plan") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"the plan {path} is not valid YAML: {' '.join(str(exc).split())}", field="plan") from None
    if not isinstance(plan, dict) or not isinstance(plan.get("base"), str) or not isinstance(plan.get("steps"), list):
        raise ConfigError("a plan is a mapping with base: FILE and steps: a list", field="plan")
    _known(plan, _PLAN_KEYS, "plan")
    folder = path.parent
    config = _with_options(config, step_options(plan.get("options"), "options", assembly_options=_ASSEMBLY_FLAGS),
                           "options")
    base_file = folder / plan["base"]
    base, steps = _steps(plan["steps"], folder, config, base_file)
    return base, str(plan.get("name") or names.default_name(base_file.name, "base")), steps, config


def _steps(entries: list, folder: Path, config, base_file: Path) -> tuple[Any, list]:
    """The base's mesh and the ``Step`` of each of ``entries`` (a plan's steps; files relative to ``folder``): every
    entry checked first, then every mesh read (``load_meshes``: one loading process for them all)."""
    from ctp_core.assembly.plan import plan_step

    parsed = [plan_step(_from_yaml(entry), f"steps.{i}", assembly_options=_ASSEMBLY_FLAGS)
              for i, entry in enumerate(entries)]
    options = [_with_options(config, s.options, f"steps.{i}.options") if s.options else None
               for i, s in enumerate(parsed)]
    base, *meshes = load_meshes([(base_file, "base")]
                                + [(folder / s.file, f"steps.{i}.file") for i, s in enumerate(parsed)])
    from ctp_core import io  # imported (trimesh with it) while the meshes were read
    from ctp_core.assembly.assemble import Step

    images = [io.load_image(folder / s.image) if s.image is not None else None for s in parsed]
    return base, [Step(source=mesh, name=s.name or names.default_name((folder / s.file).name, "object"),
                       prompt=s.prompt, image=image, on=s.on, also=s.also, config=step_config)
                  for s, mesh, image, step_config in zip(parsed, meshes, images, options, strict=True)]


def _from_yaml(entry: Any) -> Any:
    """A YAML step as the plan means it: YAML 1.1 reads the key ``on:`` as true, and bare numbers (``name: 2``)
    of the text keys, and of an ``on`` list's names (``on: [1, 2]``), as numbers."""
    if not isinstance(entry, dict):
        return entry
    entry = {("on" if key is True else key): value for key, value in entry.items()}
    if isinstance(entry.get("on"), list):
        entry["on"] = [_text(name) for name in entry["on"]]
    return {key: _text(value) if key in ("prompt", "name", "on") else value for key, value in entry.items()}


def _text(value: Any) -> Any:
    """A bare YAML number as text."""
    return str(value) if isinstance(value, int | float) else value


def _with_options(config, options: dict[str, Any], where: str):
    from ctp_core.config.options import option_overrides

    return config.merged(option_overrides(options, where))


def _known(entry: dict, keys: set[str], where: str) -> None:
    unknown = sorted(set(entry) - keys)
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(sorted(keys))}", field=where)
