"""Routers of /api/v1, one module per resource; ``api.rest.app.ROUTERS`` lists them explicitly."""
