"""Routers of /api/v1, one module per resource. Another issue adds ``gap`` (GET
/axes/{id}/gap): a module named in ``api.rest.app.ROUTERS`` is included when present."""
