"""MTConnect 2.4 response documents: MTConnectDevices (probe), MTConnectStreams
(current, sample) and MTConnectError, as XML (the standard's representation, valid
against the 2.4 XSDs; the x: observations against ``mebm_streams_2.4.xsd``) and as JSON
in the layout of the MTConnect Institute's reference agent (cppagent, JSON version 2):
the standard requires only XML ("all other protocols and representations are optional")
and defines no JSON schema, so that agent's layout is what JSON clients parse.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime
from xml.sax.saxutils import escape, quoteattr

from api.mtconnect.buffer import Observation, Window
from api.mtconnect.model import X_DEVICES_NS, X_NS, Device, iso

VERSION = "2.4.0.0"
SCHEMA_VERSION = "2.4"
NS = "urn:mtconnect.org:MTConnect{kind}:2.4"
XSD = "http://schemas.mtconnect.org/schemas/MTConnect{kind}_2.4.xsd"
XSI = "http://www.w3.org/2001/XMLSchema-instance"
X_XSD = "mebm_streams_2.4.xsd"
X_XSD_URL = "/mtconnect/schemas/" + X_XSD  # where the agent serves it
JSON_VERSION = 2


@dataclass(frozen=True)
class Header:
    sender: str
    instance_id: int
    buffer_size: int
    device_model_change_time: datetime
    creation_time: datetime


def _attrs(pairs: Iterable[tuple[str, object]]) -> str:
    return "".join(f" {k}={quoteattr(str(v))}" for k, v in pairs if v is not None)


def _root(kind: str, extra_ns: str = "", extra_loc: str = "") -> str:
    ns = NS.format(kind=kind)
    return (f'<MTConnect{kind} xmlns="{ns}" xmlns:m="{ns}" xmlns:xsi="{XSI}"{extra_ns} '
            f'xsi:schemaLocation="{ns} {XSD.format(kind=kind)}{extra_loc}">')


def _header_attrs(h: Header) -> list[tuple[str, object]]:
    return [("creationTime", iso(h.creation_time)), ("sender", h.sender), ("instanceId", h.instance_id),
            ("version", VERSION), ("deviceModelChangeTime", iso(h.device_model_change_time))]


def _number(v: float) -> str:
    return repr(float(v))


# -- probe -------------------------------------------------------------------------------------------
def devices_xml(h: Header, devices: list[Device]) -> bytes:
    # no assets: assetBufferSize must still be >= 1
    head = _header_attrs(h) + [("bufferSize", h.buffer_size), ("assetBufferSize", 1), ("assetCount", 0)]
    out = ['<?xml version="1.0" encoding="UTF-8"?>', _root("Devices", f' xmlns:x="{X_DEVICES_NS}"'),
           f"<Header{_attrs(head)}/>", "<Devices>"]
    for d in devices:
        dev = [("id", d.id), ("name", d.name), ("uuid", d.uuid), ("mtconnectVersion", SCHEMA_VERSION)]
        out.append(f"<Device{_attrs(dev)}>")
        out.append("<Description>a machine tool whose feed axes mebm monitors</Description>")
        out.append("<DataItems>" + "".join(_data_item_xml(di) for di in d.data_items) + "</DataItems>")
        if d.components:
            out.append("<Components>")
            for c in d.components:
                out.append(f"<Linear{_attrs([('id', c.id), ('name', c.name)])}>")
                out.append("<DataItems>" + "".join(_data_item_xml(di) for di in c.data_items) + "</DataItems>")
                out.append("</Linear>")
            out.append("</Components>")
        out.append("</Device>")
    out += ["</Devices>", "</MTConnectDevices>"]
    return "\n".join(out).encode()


def _data_item_attrs(di) -> list[tuple[str, object]]:
    return [("category", di.category), ("id", di.id), ("type", di.type), ("name", di.name), ("units", di.units),
            ("statistic", di.statistic)]


def _data_item_xml(di) -> str:
    return f"<DataItem{_attrs(_data_item_attrs(di))}/>"


def devices_json(h: Header, devices: list[Device]) -> bytes:
    def items(dis):
        return {"DataItem": [{k: v for k, v in _data_item_attrs(di) if v is not None} for di in dis]}

    devs = []
    for d in devices:
        dev = {"id": d.id, "name": d.name, "uuid": d.uuid, "mtconnectVersion": SCHEMA_VERSION,
               "Description": {"value": "a machine tool whose feed axes mebm monitors"},
               "DataItems": items(d.data_items)}  # fmt: skip
        if d.components:
            dev["Components"] = {"Linear": [{"id": c.id, "name": c.name, "DataItems": items(c.data_items)}
                                            for c in d.components]}  # fmt: skip
        devs.append(dev)
    header = dict(_header_attrs(h), bufferSize=h.buffer_size, assetBufferSize=1, assetCount=0)
    return _json({"MTConnectDevices": {"jsonVersion": JSON_VERSION, "schemaVersion": SCHEMA_VERSION,
                                       "Header": header, "Devices": {"Device": devs}}})


# -- current, sample -----------------------------------------------------------------------------------
def _streams_header(h: Header, w: Window) -> list[tuple[str, object]]:
    return _header_attrs(h) + [("bufferSize", h.buffer_size), ("nextSequence", w.next),
                               ("firstSequence", w.first), ("lastSequence", w.last)]


def _group(devices: list[Device], obs: Iterable[Observation]):
    """Observations per device and component, in the probe's order; each list in sequence order."""
    order = {}
    for d in devices:
        order[d.id] = (d, {d.id: ("Device", d.name, [])} | {c.id: ("Linear", c.name, []) for c in d.components})
    for o in obs:
        dev = order.get(o.device)
        if dev is not None and o.component in dev[1]:
            dev[1][o.component][2].append(o)
    for d, comps in order.values():
        streams = [(cid, kind, name, lst) for cid, (kind, name, lst) in comps.items() if lst]
        if streams:
            yield d, streams


def _obs_attrs(o: Observation) -> list[tuple[str, object]]:
    v, di = o.v, o.v.data_item
    attrs = [("dataItemId", di.id), ("timestamp", iso(v.timestamp)), ("sequence", o.sequence), ("name", di.name)]
    if di.category == "CONDITION":
        attrs += [("type", di.type), ("nativeCode", v.native_code),
                  ("qualifier", "HIGH" if v.level in ("Warning", "Fault") else None)]
        if v.level in ("Warning", "Fault"):
            attrs.append(("conditionId", v.condition_id))
    elif di.statistic:
        attrs.append(("statistic", di.statistic))
    return attrs


def _obs_text(o: Observation):
    v = o.v
    if v.data_item.category == "CONDITION":
        return v.value or ""
    if v.value is None:
        return "UNAVAILABLE"
    return v.value if isinstance(v.value, str) else float(v.value)


def streams_xml(h: Header, devices: list[Device], w: Window) -> bytes:
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           _root("Streams", f' xmlns:x="{X_NS}"', f" {X_NS} {X_XSD_URL}"),
           f"<Header{_attrs(_streams_header(h, w))}/>", "<Streams>"]
    for d, streams in _group(devices, w.observations):
        out.append(f"<DeviceStream{_attrs([('name', d.name), ('uuid', d.uuid)])}>")
        for cid, kind, name, lst in streams:
            out.append(f"<ComponentStream{_attrs([('component', kind), ('name', name), ('componentId', cid)])}>")
            for cat, wrapper in (("SAMPLE", "Samples"), ("EVENT", "Events"), ("CONDITION", "Condition")):
                part = [o for o in lst if o.v.data_item.category == cat]
                if not part:
                    continue
                out.append(f"<{wrapper}>")
                for o in part:
                    tag = o.v.level if cat == "CONDITION" else o.v.data_item.element
                    text = _obs_text(o)
                    text = _number(text) if isinstance(text, float) else escape(text)
                    attrs = _attrs(_obs_attrs(o))
                    out.append(f"<{tag}{attrs}>{text}</{tag}>" if text else f"<{tag}{attrs}/>")
                out.append(f"</{wrapper}>")
            out.append("</ComponentStream>")
        out.append("</DeviceStream>")
    out += ["</Streams>", "</MTConnectStreams>"]
    return "\n".join(out).encode()


def streams_json(h: Header, devices: list[Device], w: Window) -> bytes:
    dstreams = []
    for d, streams in _group(devices, w.observations):
        cs = []
        for cid, kind, name, lst in streams:
            entry = {"component": kind, "name": name, "componentId": cid}
            for cat, wrapper in (("SAMPLE", "Samples"), ("EVENT", "Events"), ("CONDITION", "Condition")):
                part = [o for o in lst if o.v.data_item.category == cat]
                if not part:
                    continue
                group: dict[str, list] = {}
                for o in part:
                    key = o.v.level if cat == "CONDITION" else o.v.data_item.element
                    ob = dict(_obs_attrs(o))
                    ob = {k: v for k, v in ob.items() if v is not None}
                    text = _obs_text(o)
                    if cat != "CONDITION" or text:
                        ob["value"] = text
                    group.setdefault(key, []).append(ob)
                entry[wrapper] = group
            cs.append(entry)
        dstreams.append({"name": d.name, "uuid": d.uuid, "ComponentStream": cs})
    return _json({"MTConnectStreams": {"jsonVersion": JSON_VERSION, "schemaVersion": SCHEMA_VERSION,
                                       "Header": dict(_streams_header(h, w)),
                                       "Streams": {"DeviceStream": dstreams} if dstreams else {}}})


# -- assets --------------------------------------------------------------------------------------------
def assets_xml(h: Header) -> bytes:
    """An empty MTConnectAssets document: mebm has no assets (tools, parts, programs), but
    clients that poll /assets get the agent's answer, not an error."""
    head = _header_attrs(h) + [("assetBufferSize", 1), ("assetCount", 0)]
    return "\n".join(['<?xml version="1.0" encoding="UTF-8"?>', _root("Assets"), f"<Header{_attrs(head)}/>",
                      "<Assets/>", "</MTConnectAssets>"]).encode()  # fmt: skip


def assets_json(h: Header) -> bytes:
    head = dict(_header_attrs(h), assetBufferSize=1, assetCount=0)
    return _json({"MTConnectAssets": {"jsonVersion": JSON_VERSION, "schemaVersion": SCHEMA_VERSION, "Header": head,
                                      "Assets": {}}})


# -- errors --------------------------------------------------------------------------------------------
def _error_header(h: Header) -> list[tuple[str, object]]:
    # the Error document's Header has no deviceModelChangeTime
    return [("creationTime", iso(h.creation_time)), ("sender", h.sender), ("instanceId", h.instance_id),
            ("version", VERSION), ("bufferSize", h.buffer_size)]


def error_xml(h: Header, code: str, message: str) -> bytes:
    head = _error_header(h)
    return "\n".join(['<?xml version="1.0" encoding="UTF-8"?>', _root("Error"), f"<Header{_attrs(head)}/>",
                      f"<Errors><Error errorCode={quoteattr(code)}>{escape(message)}</Error></Errors>",
                      "</MTConnectError>"]).encode()  # fmt: skip


def error_json(h: Header, code: str, message: str) -> bytes:
    head = dict(_error_header(h))
    return _json({"MTConnectError": {"jsonVersion": JSON_VERSION, "schemaVersion": SCHEMA_VERSION, "Header": head,
                                     "Errors": {"Error": [{"errorCode": code, "value": message}]}}})


def _json(doc: dict) -> bytes:
    return json.dumps(doc, ensure_ascii=False, separators=(",", ":")).encode()
