"""``ctp compose``: a scene from one sentence: the description read into a plan, the plan placed as ``ctp
assemble`` places one (``ctp_core.assembly.describe``, then ``cmd_assemble.run_assembly``).

    ctp compose piano.glb stool.glb metronome.glb \\
        --prompt "a piano with its stool in front of it and a metronome on top"
    ctp compose a.glb b.glb --names workbench toolbox --prompt "a toolbox on the workbench" --dry-run

Objects are named by ``--names`` (one per file, in order), else by their file names (``paint_tin.glb``: "paint
tin"); a description that names none of them matches them in the order it names its objects. The object that
supports others and is supported by none stays put (its file frame is the scene frame); an object the description
never places goes on the floor beside it, said on stderr. ``--reader openai`` asks an OpenAI-compatible endpoint
(``CTP_LLM_*``) for the plan, the rules on any failure. ``--dry-run`` prints the plan as ``ctp assemble --plan``
reads it (paths as given here; each step's reading, what it stands on, its other relations and its warnings in
comments) and exits: save it, edit it, run it with ``ctp assemble --plan``. The GLB has one node per object (copies
``<name>_1`` ...), the report every stage and, under ``whole``, every relation judged again on the final scene.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from ctp.cmd_align import add_run_arguments, config_from_args, load_meshes
from ctp.cmd_assemble import run_assembly
from ctp_core.assembly.describe import ScenePlan
from ctp_core.assembly.readers import READERS, get_reader
from ctp_core.errors import ConfigError
from ctp_core.reading import names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = __doc__.split("\n\n", 1)[1]  # the examples and what is read how
    parser.add_argument("objects", type=Path, nargs="+", metavar="OBJECT", help="the meshes the description names")
    parser.add_argument("--prompt", required=True, metavar="TEXT",
                        help='the scene in one sentence ("a piano with its stool in front of it and a metronome '
                        'on top")')
    parser.add_argument("--names", nargs="+", metavar="NAME", help="what each OBJECT is, in order, given after the "
                        "OBJECTs (default: the file names)")
    parser.add_argument("--reader", choices=READERS, default=None, help="who reads the description: the rules "
                        "(default, CTP_PLAN_READER) or an OpenAI-compatible endpoint (CTP_LLM_*; the rules on any "
                        "failure)")
    parser.add_argument("--dry-run", action="store_true", help="print the plan (YAML, as ctp assemble --plan reads "
                        "it) and exit")
    add_run_arguments(parser)


def run(args: argparse.Namespace) -> int:
    called = args.names or [names.default_name(path.name, "object") for path in args.objects]
    if len(called) != len(args.objects):
        raise ConfigError(f"--names gives {len(called)} names for {len(args.objects)} objects: one each",
                          field="names")
    plan = get_reader(args.reader).read(args.prompt, called)
    if args.dry_run:
        print(plan_yaml(plan, [str(path) for path in args.objects]), end="")
        return 0
    for warning in plan.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    config = config_from_args(args)
    meshes = load_meshes([(path, f"objects.{i}") for i, path in enumerate(args.objects)])
    from ctp_core.assembly.assemble import Step  # imported (trimesh with it) while the meshes were read

    steps = [Step(source=meshes[s.upload].copy(), name=s.name, prompt=s.prompt, on=list(s.on),
                  also=s.also) for s in plan.steps]
    return run_assembly(args, meshes[plan.base_upload], plan.base, steps, config, plan=plan.to_dict())


def plan_yaml(plan: ScenePlan, files: list[str]) -> str:
    """The plan as ``ctp assemble --plan`` reads it, after comments with the description, what was assumed and
    each step's reading."""
    lines = [f"# {plan.description}", f"# read by {plan.reader}", f"# {plan.base} stays put (on the floor)"]
    for i, s in enumerate(plan.steps, start=1):
        lines.append(f"# {i}. {s.name}: {s.relation} {' and '.join(s.on)}; stands on {s.support}"
                     + (f" (said: '{s.said}')" if s.said else ""))
        lines += [f"#    also {a.relation} {' and '.join(a.on)}" for a in s.also]
        lines += [f"#    warning: {w}" for w in s.warnings]
    lines += [f"# warning: {w}" for w in plan.warnings if not any(w in s.warnings for s in plan.steps)]
    return "\n".join(lines) + "\n" + yaml.safe_dump(plan.assembly_plan(files), sort_keys=False, width=110)
