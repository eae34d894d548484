"""The name of this installation, on every interface: the MQTT topics and payloads, the
MTConnect devices' uuids, the OPC UA namespace, the webhooks' messages.

Two installations may watch machines of the same name (each plant has its ``vmc-1``) and
publish to one broker or one MES; the installation's name keeps them apart. It is
``[service] instance`` in the configuration file, or ``MEBM_INSTANCE``; without either,
``mebm-<8 hex digits>`` drawn at random once and kept in ``<data_dir>/installation-id``,
so every installation has a name of its own and keeps it across restarts. The workers of
one fleet (docs/fleet.md) are one installation: give them one ``instance``.
"""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from api.service.config.settings import ConfigError, Settings

INSTALLATION_FILE = "installation-id"  # in the data folder
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def check_instance(name: str, where: str) -> str:
    """``name`` if it can be an MQTT topic level, part of a URN and of a client id as it
    is; a ConfigError naming ``where`` otherwise."""
    if not NAME.fullmatch(name):
        raise ConfigError(f"{where} (={name!r}) must be 1-64 characters of letters, digits, '.', '_' or '-', "
                          "beginning with a letter or digit (it is a topic level and part of a URN)")
    return name


def installation_name(settings: Settings) -> str:
    """The configured instance, else the one kept in the data folder (drawn and kept there
    the first time). ConfigError when the folder cannot keep it."""
    if settings.instance:
        return settings.instance
    path = Path(settings.data_dir) / INSTALLATION_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        try:  # O_EXCL: two processes starting on one folder draw one name
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            pass
        else:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(f"mebm-{secrets.token_hex(4)}\n")
                f.flush()
                os.fsync(f.fileno())
        name = path.read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise ConfigError(f"the installation's name cannot be kept in {path} ({exc.strerror or exc}): set "
                          "[service] instance in the configuration file or MEBM_INSTANCE") from exc
    return check_instance(name, str(path))
