"""MTConnect: an agent-compatible, read-only HTTP interface (MTConnect 2.4) under
``/mtconnect`` on the API's port.

Each machine is a ``Device``, each axis a ``Linear`` component carrying b̄ and its
uncertainty, the backlash limit, the TBE of each machining task, the temperature, the
last cycle's time and status, and a ``CONDITION`` with the maintenance state
(``model.py``). Observations are numbered in a ring buffer (``buffer.py``) filled from
the service's events and seeded from the database at start (``agent.py``); ``probe``,
``current`` and ``sample`` serve it as XML or JSON (``documents.py``, ``routes.py``).

The REST app mounts :func:`make_router`; this package imports neither REST nor the CLI.
"""

from api.mtconnect.agent import MTConnectAgent
from api.mtconnect.routes import PREFIX, make_router

__all__ = ["MTConnectAgent", "PREFIX", "make_router"]
