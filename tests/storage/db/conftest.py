from tests.storage.db.backends import db_url, engine  # noqa: F401 - fixtures
