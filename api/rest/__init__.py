"""The REST API (FastAPI) of the mebm service: ``create_app(settings)``."""

from api.rest.app import create_app

__all__ = ["create_app"]
