"""ctp_core: the Copy-Transform-Paste engine (no web or queue code).

A package of families, one per stage; data flows one way: load (``io``, ``orientation``) -> normalise
(``geometry.frames``) -> prepare (``pairs``) -> guide (``guide``) -> relations and contact (``relations``,
``contact``) -> judge (``objective``) -> search (``search``) -> optimise (``optimise``) -> align and export
(``align``, ``export``). The layers and what each family holds: docs/engine.md, "Layout"; the import rules:
tests/test_imports.py.
"""

__version__ = "0.1.0"
