"""Annotated dependencies shared by the routers."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Request
from sqlalchemy.orm import Session

from api.service.service import Service
from storage.db import session_scope


async def get_service(request: Request) -> Service:
    return request.app.state.service


def get_session(request: Request) -> Iterator[Session]:
    with session_scope(request.app.state.service.factory) as s:
        yield s


ServiceDep = Annotated[Service, Depends(get_service)]
SessionDep = Annotated[Session, Depends(get_session)]
# Ids are positive 31-bit (PostgreSQL integer) integers: anything else is a 422 naming the field, never a 500.
AxisId = Annotated[int, Path(ge=1, le=2**31 - 1, description="axis id")]
MachineId = Annotated[int, Path(ge=1, le=2**31 - 1, description="machine id")]
MeasurementId = Annotated[int, Path(ge=1, le=2**31 - 1, description="measurement (cycle) id")]
AlertId = Annotated[int, Path(ge=1, le=2**31 - 1, description="alert id")]
KeyId = Annotated[int, Path(ge=1, le=2**31 - 1, description="key id")]
