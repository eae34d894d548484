"""/webhooks/deliveries, /webhooks/messages and /interfaces: what the publishers and the OPC UA
server did."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request

from api.rest.auth import AdminKey, ReadKey
from api.rest.deps import SessionDep
from storage.db import utcnow, webhooks_repo

router = APIRouter(tags=["interfaces"])


@router.get("/interfaces", summary="Which event interfaces are on, and their counters")
def interfaces(request: Request, _k: ReadKey) -> dict:
    st = request.app.state
    mqtt, hooks = st.mqtt, st.webhooks
    subs = {s.name: {"pending": s.pending, "delivered": s.delivered, "dropped": s.dropped, "failed": s.failed}
            for s in st.service.events.subscriptions}  # fmt: skip
    return {
        "instance": st.service.instance,  # this installation's name in the topics, uuids and namespace
        "mqtt": None if mqtt is None else {
            "broker": f"{mqtt.host}:{mqtt.port}", "topic_prefix": mqtt.prefix, "topics": f"{mqtt.base}/<machine>/<axis>/status|alerts|maintenance",
            "connected": mqtt.connections(),
            "alerts_acknowledged": mqtt.published, "alerts_dropped": mqtt.dropped},
        "webhooks": None if hooks is None else {
            "urls": len(hooks.settings.urls), "delivered": hooks.delivered, "failed_attempts": hooks.failed,
            "given_up": hooks.given_up, "waiting_for_database": hooks.unstored,
            "dropped_database_unreachable": hooks.unstored_dropped, "failed_deleted": hooks.purged_failed},
        "opcua": None if st.opcua is None else st.opcua.describe(),
        "mtconnect": _mtconnect(st),
        "event_consumers": subs,
    }  # fmt: skip


def _mtconnect(st) -> dict | None:
    agent = getattr(st, "mtconnect", None)
    if agent is None:
        return None
    first, last, nxt = agent.buffer.bounds()
    return {"path": "/mtconnect", "require_key": agent.settings.require_key, "instance_id": agent.instance_id,
            "buffer_size": agent.buffer.size, "first_sequence": first, "last_sequence": last,
            "next_sequence": nxt, "devices": len(agent.devices())}


@router.get("/webhooks/deliveries", summary="The webhook delivery log, newest first (admin)")
def deliveries(request: Request, _k: AdminKey, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[dict]:
    hooks = request.app.state.webhooks
    return [] if hooks is None else hooks.log_entries()[:limit]


@router.get("/webhooks/messages", summary="Webhook messages kept in the database, newest first (admin): "
            "pending, delivered (purged after webhooks.keep_delivered_days) or failed (every attempt used)")
def messages(s: SessionDep, _k: AdminKey,
             state: Annotated[str | None, Query(pattern="^(pending|delivered|failed)$")] = None,
             limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> dict:
    rows = webhooks_repo.list_messages(s, state=state, limit=limit)
    return {"counts": webhooks_repo.counts(s), "items": [
        {"id": m.id, "webhook_id": m.msg_id, "url": m.url, "type": m.event_type, "axis_id": m.axis_id,
         "state": m.state, "attempts": m.attempts, "created_at": m.created_at, "next_at": m.next_at,
         "last_status": m.last_status, "last_error": m.last_error, "done_at": m.done_at}
        for m in rows]}  # fmt: skip


@router.post("/webhooks/messages/retry", summary="Send every failed webhook message again (admin), "
             "e.g. once the receiver is back; each keeps its webhook-id")
def retry(request: Request, s: SessionDep, _k: AdminKey) -> dict:
    n = webhooks_repo.requeue_failed(s, utcnow())
    s.commit()
    hooks = request.app.state.webhooks
    if hooks is not None:
        hooks.wake()
    return {"requeued": n}
