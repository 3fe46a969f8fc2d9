"""The ``ctp`` command line: thin wiring around ``ctp_core`` (engine), ``service`` and ``worker``."""
