"""The API's routes, one router per concept: ``health`` (liveness, readiness) and ``jobs`` (submit, state,
cancel, events, results). ``service.app.create_app`` includes them."""
