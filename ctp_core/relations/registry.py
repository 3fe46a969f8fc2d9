"""The relations the engine knows: one ``Spec`` per relation record, gathered from the kind modules.

Adding a relation with one ground: its name and record in ``reading.records`` (``RelationName``, ``RELATIONS``), its
wordings in ``reading.cues.CUES``, its spec (score, preference, builder, scale bound, usual place) in the kind module
it belongs to, its tests, and its entry in docs/relations.md. Nothing else names it; ``check`` (run by the tests)
says what is inconsistent.
"""

from __future__ import annotations

from ctp_core.reading.records import RELATIONS, RelationName
from ctp_core.relations import apart, attached, contained, resting
from ctp_core.relations.spec import Spec

SPECS: dict[RelationName, Spec] = {**resting.SPECS, **contained.SPECS, **attached.SPECS, **apart.SPECS}


def check(specs: dict[RelationName, Spec]) -> list[str]:
    """What is inconsistent between ``specs`` and the records (empty when nothing is)."""
    problems = [f"{name}: a record without a spec" for name in RELATIONS if name not in specs]
    problems += [f"{name}: a spec without a record" for name in specs if name not in RELATIONS]
    problems += [f"{name}: filed under another name" for name, spec in specs.items() if spec.name != name]
    problems += [f"{name}: rests on its ground but is not judged as resting" for name, r in RELATIONS.items()
                 if r.rests and specs.get(name) is not None and specs[name].judge.score is not resting.score_resting]
    return problems
