"""The API's routes, one router per concept: ``health`` (liveness, readiness), ``jobs`` (submit, list, state,
cancel, events, results), ``assemble`` (``POST /assemble``) and ``page`` (the web page, its static files and the
offline docs; not in the schema). ``service.app.create_app`` includes them; ``POST /align``'s chained target is
``service.chained``."""
