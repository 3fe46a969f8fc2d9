"""The relations the engine knows: one ``Spec`` per relation of the vocabulary, gathered from the kind modules.

Adding a relation with one ground: its record and wordings in ``vocabulary`` (``RELATIONS``, ``CUES``), its spec
(score, preference, builder, scale bound, usual place) in the kind module it belongs to, its tests, and its entry in
docs/relations.md. Nothing else names it.
"""

from __future__ import annotations

from ctp_core.relations import apart, attached, contained, resting
from ctp_core.relations.spec import Spec
from ctp_core.relations.vocabulary import RELATIONS

SPECS: dict[str, Spec] = {**resting.SPECS, **contained.SPECS, **attached.SPECS, **apart.SPECS}


def check(specs: dict[str, Spec]) -> list[str]:
    """What is inconsistent between ``specs`` and the vocabulary (empty when nothing is)."""
    problems = [f"{name}: a record without a spec" for name in RELATIONS if name not in specs]
    problems += [f"{name}: a spec without a record" for name in specs if name not in RELATIONS]
    problems += [f"{name}: filed under another name" for name, spec in specs.items() if spec.name != name]
    problems += [f"{name}: rests on its ground but is not judged as resting" for name, r in RELATIONS.items()
                 if r.rests and specs.get(name) is not None and specs[name].judge.score is not resting.score_resting]
    return problems


assert not check(SPECS), check(SPECS)
