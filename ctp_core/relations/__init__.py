"""The relations as the geometry knows them, keyed by the names of ``reading.records``: one spec per relation
(``spec``, ``registry.SPECS``) defined by the kind modules (``resting``, ``contained``, ``attached``, ``apart``),
what their judges share (``measures``) and their builders share (``building``), the ground's parts the usual places
are on (``parts``, its registry ``PARTS``), the judging API (``predicates``) and the search's use of the builders
(``builders``). docs/relations.md says each relation's definition and usual place, and how to add a relation or a
part.
"""
