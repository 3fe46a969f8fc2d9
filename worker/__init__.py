"""The queue worker: runs ``ctp_core.align`` for jobs queued by ``service`` and stores their results."""
