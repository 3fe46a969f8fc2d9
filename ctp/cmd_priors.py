"""``ctp priors`` (``ctp hparams``, its deprecated alias): print the scene priors for a (target, source,
prompt) triple as JSON (the report's ``hparams`` entry, without the names).

What ``ctp align`` would use, without loading a mesh or a model: handy to check a prompt's reading
before a long run, or to test an LLM endpoint (``--provider openai`` with CTP_LLM_* set). A prompt that says
several of the source ("three apples") adds ``copies``: the number, the arrangement, and what each copy is read as.
Exit codes: 0 printed; 2 bad input (one line on stderr: ``error: CODE: message``).
"""

from __future__ import annotations

import argparse
import json
import math

from ctp_core import priors
from ctp_core.config import PENETRATION
from ctp_core.errors import ConfigError
from ctp_core.reading import counts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # Values are parsed in run() so that bad input is one line, like every other error.
    parser.add_argument("--target", required=True, metavar="NAME",
                        help="target object name (e.g. plate, christmas_tree)")
    parser.add_argument("--source", required=True, metavar="NAME", help="source object name (the one placed)")
    parser.add_argument("--prompt", default="", metavar="TEXT", help="text describing the arrangement (optional: "
                        "relation cues such as on, inside, embedded in)")
    parser.add_argument("--provider", default=priors.PROVIDERS[0], metavar="NAME",
                        help=f"{' | '.join(priors.PROVIDERS)} (default {priors.PROVIDERS[0]})")
    parser.add_argument("--size-ratio", metavar="S", help="explicit source/target size in [0.01, 100]")
    parser.add_argument("--penetration", default="auto", metavar="|".join(PENETRATION), help=" | ".join(PENETRATION))
    parser.add_argument("--contact-ratio", metavar="R", help="explicit soft-ICP ratio in [0, 1]")
    parser.add_argument("--target-extent", metavar="L",
                        help="target mesh longest side in file units (may inform the size)")
    parser.add_argument("--source-extent", metavar="L", help="source mesh longest side in file units")


def run(args: argparse.Namespace) -> int:
    for flag in ("target", "source"):
        if not (getattr(args, flag) or "").strip():
            raise ConfigError(f"--{flag} NAME is required", field=flag)
    if args.penetration not in PENETRATION:
        raise ConfigError(f"--penetration must be one of {', '.join(PENETRATION)}, got {args.penetration!r}",
                          field="penetration")
    prior = priors.resolve_priors(
        priors.get_provider(args.provider), args.target, args.source, args.prompt,
        size_ratio=_number(args.size_ratio, "size-ratio"), penetration=PENETRATION[args.penetration],
        contact_ratio=_number(args.contact_ratio, "contact-ratio"),
        target_extent=_number(args.target_extent, "target-extent"),
        source_extent=_number(args.source_extent, "source-extent"),
    )
    out = priors.to_report(prior.to_dict())
    said = counts.read_count(args.prompt, args.source)
    if said.count is not None or said.arrangement is not None:  # several of a kind: what each copy is read as
        one = counts.one_copy(args.prompt, said.arrangement or "scatter")
        copy = priors.get_provider(args.provider).estimate(args.target, args.source, one)
        judged = counts.AROUND if said.arrangement == "around" else copy.reading
        out["copies"] = {**said.to_dict(), "copy_prompt": one, "copy_relation": None if judged is None else judged.name}
    print(json.dumps(out, indent=2))
    return 0


def _number(text: str | None, flag: str) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"--{flag} must be a number, got {text!r}", field=flag.replace("-", "_")) from None
    if not math.isfinite(value):
        raise ConfigError(f"--{flag} must be finite, got {text!r}", field=flag.replace("-", "_"))
    return value
