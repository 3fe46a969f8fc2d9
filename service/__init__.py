"""ctp as an HTTP service: a FastAPI app over Redis and rq; the engine runs in ``worker``."""
