"""ctp_core: the Copy-Transform-Paste engine (no web or queue code).

Data flows one way: ``io`` (load, file frame) -> ``frames`` (normalise) -> ``orientation`` (up and front: the
file's first, ``canonical``'s guess when asked) -> ``optimise`` (pose search with ``render`` + ``guidance`` +
``losses``) -> ``export`` (GLB, report).
"""

__version__ = "0.1.0"
