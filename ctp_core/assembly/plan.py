"""The assembly plan as written: what a step may say, checked for shape before any mesh is read.

The vocabulary ``ctp assemble --plan`` and ``POST /assemble`` share (``plan_step``, ``check_plan``);
``assemble`` runs a checked plan. Kept free of trimesh and torch so the API checks plans without them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ctp_core.errors import ConfigError
from ctp_core.reading.names import ground_names

__all__ = ["MAX_GROUNDS", "STEP_KEYS", "Also", "PlanError", "PlanStep", "check_plan", "plan_step",
           "step_options"]

MAX_GROUNDS = 2  # objects one step relates to: one, or two ("a lamp between the sofa and the armchair")
STEP_KEYS = frozenset({"file", "prompt", "image", "name", "on", "also", "options"})  # one step of a plan
ALSO_KEYS = frozenset({"prompt", "on", "relation"})  # one relation said of a step's object besides its own
_ASSEMBLY_ONLY = frozenset({"preset", "model"})  # the whole assembly's: one model is loaded for every stage


class PlanError(ConfigError):
    """A plan step of the wrong shape (a bad option value is a plain ``ConfigError``): the CLI prints it,
    the API answers 400 ``invalid_plan``."""



@dataclass(frozen=True)
class Also:
    """A relation said of a step's object besides the one that places it ("the lamp on the desk, to the right of
    the monitor": placed on the desk, right of the monitor as well): its prompt, read as a pair prompt with the
    step's object as the figure, and the objects it relates to (``on``, placed by the plan). The assembly judges it
    with the step (a placement that breaks it is retried among the run's alternatives) and on the final scene.
    ``relation``: the reading's name where a reader filled it in (reports only)."""

    prompt: str
    on: tuple[str, ...]
    relation: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"prompt": self.prompt, "on": list(self.on), "relation": self.relation}

    @classmethod
    def from_dict(cls, entry: dict[str, Any]) -> Also:
        """``to_dict``'s inverse (a report's or a job record's entry, already checked)."""
        return cls(entry["prompt"], tuple(entry["on"]), entry.get("relation") or "")


@dataclass(frozen=True)
class PlanStep:
    """One step of a plan as written (``file`` and ``image`` name files; the adapters read them). ``on``, given as
    a name or a list of names, is kept as the tuple of the placed objects it relates to (empty: the default)."""

    file: str
    prompt: str | None = None
    image: str | None = None
    name: str | None = None  # None: the adapter's default (the file stem)
    on: tuple[str, ...] = ()
    also: tuple[Also, ...] = ()
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "on", ground_names(self.on))


def plan_step(entry: Any, where: str, *, assembly_options: str) -> PlanStep:
    """A plan step (a mapping of ``STEP_KEYS``) checked for shape: ``file`` given, no unknown key, the text
    keys strings, ``on`` a name or a list of one or two distinct names, a prompt or an image (not both),
    ``options`` a mapping without preset and model (set for the whole assembly where ``assembly_options`` says).
    Raises ``PlanError`` with ``field`` ``<where>[.<key>]``."""
    if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
        raise PlanError(f"{where}: a step is a mapping with file: its source's file name", field=where)
    unknown = sorted(set(entry) - STEP_KEYS, key=str)
    if unknown:
        raise PlanError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(sorted(STEP_KEYS))}",
                        field=f"{where}.{unknown[0]}")
    for key in ("prompt", "image", "name"):
        if entry.get(key) is not None and not isinstance(entry[key], str):
            raise PlanError(f"{where}.{key} must be a string", field=f"{where}.{key}")
    if entry.get("prompt") is not None and entry.get("image") is not None:
        raise PlanError(f"{where}: give a prompt or an image, not both", field=f"{where}.prompt")
    return PlanStep(file=entry["file"], prompt=entry.get("prompt"), image=entry.get("image"), name=entry.get("name"),
                    on=_on(entry.get("on"), f"{where}.on"), also=_also(entry.get("also"), f"{where}.also"),
                    options=step_options(entry.get("options"), f"{where}.options", assembly_options=assembly_options))


def _on(on: Any, where: str) -> tuple[str, ...]:
    """A step's ``on``: absent, a name, or a list of 1 to ``MAX_GROUNDS`` distinct names."""
    if on is None or isinstance(on, str):
        return ground_names(on)
    if not isinstance(on, list) or not 1 <= len(on) <= MAX_GROUNDS or not all(isinstance(n, str) for n in on):
        raise PlanError(f"{where} must be a name or a list of 1 to {MAX_GROUNDS} names", field=where)
    if len(set(on)) < len(on):
        raise PlanError(f"{where} names {on[0]!r} twice; the grounds are different objects", field=where)
    return tuple(on)


def _also(also: Any, where: str) -> tuple[Also, ...]:
    """A step's ``also``: absent, or a list of mappings, each a ``prompt`` and the ``on`` it relates to."""
    if also is None:
        return ()
    if not isinstance(also, list):
        raise PlanError(f"{where} must be a list of {{prompt, on}} mappings", field=where)
    out = []
    for k, entry in enumerate(also):
        here = f"{where}.{k}"
        if not isinstance(entry, dict) or not isinstance(entry.get("prompt"), str) or not entry["prompt"].strip():
            raise PlanError(f"{here} must be a mapping with prompt: the relation in words", field=here)
        unknown = sorted(set(entry) - ALSO_KEYS, key=str)
        if unknown:
            raise PlanError(f"{here}: unknown key {unknown[0]!r}; known: {', '.join(sorted(ALSO_KEYS))}",
                            field=f"{here}.{unknown[0]}")
        on = _on(entry.get("on"), f"{here}.on")
        if not on:
            raise PlanError(f"{here}.on must name the object(s) the relation is to", field=f"{here}.on")
        out.append(Also(entry["prompt"], on, str(entry.get("relation") or "")))
    return tuple(out)


def step_options(options: Any, where: str, *, assembly_options: str) -> dict[str, Any]:
    """Run options that apply per stage (``None``: none): a mapping without preset and model."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise PlanError(f"{where} must be a mapping of option names to values", field=where)
    if _ASSEMBLY_ONLY & set(options):
        raise PlanError(f"{where}: preset and model are set for the whole assembly ({assembly_options})", field=where)
    return options


def check_plan(base_name: str, steps: Sequence[tuple[str, Sequence[str], bool]]) -> None:
    """Each step's (name, on: the names of the objects it relates to, guided): names unique and non-empty, every
    name in ``on`` an object placed before it, a prompt or an image wherever the guidance term is on. Raises
    ConfigError naming the step."""
    if not steps:
        raise ConfigError("an assembly needs at least one step", field="steps")
    names = [base_name]
    for i, (name, on, guided) in enumerate(steps):
        if not name or not name.strip():
            raise ConfigError(f"step {i + 1} has no name", field=f"steps.{i}.name")
        if name in names:
            raise ConfigError(f"step {i + 1}: the name {name!r} is already used; names must be unique",
                              field=f"steps.{i}.name")
        for ground in ground_names(on):
            if ground not in names:
                raise ConfigError(f"step {i + 1} ({name}): on {ground!r} is not an object placed before it "
                                  f"({', '.join(names)})", field=f"steps.{i}.on")
        if not guided:
            raise ConfigError(f"step {i + 1} ({name}) needs a prompt or an image", field=f"steps.{i}.prompt")
        names.append(name)
