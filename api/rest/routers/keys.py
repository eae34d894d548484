"""/keys: access keys (admin). The secret is returned once, at creation."""

from __future__ import annotations

from fastapi import APIRouter, Request, status

from api.rest import convert, schemas as sc
from api.rest.auth import AdminKey
from api.rest.deps import KeyId, SessionDep
from storage.db import ConflictError, config_repo

router = APIRouter(tags=["keys"])


@router.get("/keys", response_model=list[sc.KeyOut], summary="All keys (admin)")
def list_keys(s: SessionDep, _k: AdminKey):
    return [convert.key(k) for k in config_repo.list_keys(s)]


@router.post("/keys", response_model=sc.KeyCreated, status_code=status.HTTP_201_CREATED, summary="Create a key (admin)")
def create_key(body: sc.KeyIn, s: SessionDep, _k: AdminKey):
    rec, secret = config_repo.create_key(s, body.name, body.role)
    return sc.KeyCreated(**convert.key(rec).model_dump(), key=secret)


@router.delete("/keys/{key_id}", response_model=sc.KeyOut, summary="Revoke a key (admin)")
def revoke_key(key_id: KeyId, s: SessionDep, request: Request, key: AdminKey):
    if key_id == key.id:
        raise ConflictError("a key cannot revoke itself: use another admin key")
    rec = config_repo.revoke_key(s, key_id)
    out = convert.key(rec)
    s.commit()  # committed before the cache is cleared: no request can find the key valid again
    request.app.state.key_cache.clear()  # every interface of this process refuses it from now on
    return out
