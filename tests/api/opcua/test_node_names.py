"""Names of machines and tasks in the address space never collide with another node:
a machine named like one of the address space's own folders, or like the server's
standard nodes, is a node of its own beside the others (an in-process asyncua server)."""

from __future__ import annotations

import asyncio

from asyncua import Server, ua

from api.opcua.nodes import NAMESPACE_URI, AddressSpace, segment
from api.opcua.values import AxisValues, TaskValue


def _values(axis_id: int, machine: str, tasks: tuple[str, ...] = ()) -> AxisValues:
    return AxisValues(axis_id=axis_id, machine=machine, axis="y", state="OK", message="ok", measured_at=None,
                      backlash_mean_um=None, backlash_mean_uncertainty_um=None, backlash_limit_um=None,
                      restore_below_um=None, restore_below_explanation=None,
                      tasks=tuple(TaskValue(t, None, 45.0, None) for t in tasks), predicted_time=None,
                      prediction_source=None)


def test_a_name_that_reads_like_a_path_escapes_its_slashes():
    assert segment("x/Notification") == "x%2FNotification"
    assert segment("a%2Fb") == "a%252Fb" != segment("a/b")
    assert segment("vmc 850") == "vmc 850"


def test_machines_named_like_the_address_space_s_nodes_are_each_seeded():
    machines = ["x", "x/Notification", "x/Notification/Prognoses", "Server", "Objects", "Machines", "Root"]

    async def go() -> dict[str, list[str]]:
        srv = Server()
        await srv.init()
        try:
            idx = await srv.register_namespace(NAMESPACE_URI)
            space = AddressSpace(srv, idx)
            await space.build()
            for i, m in enumerate(machines, start=1):
                await space.apply(_values(i, m, tasks=("a", "a/Tolerance")))
            folder = await srv.nodes.objects.get_child(f"{idx}:Machines")
            seen = {}
            for node in await folder.get_children():
                name = (await node.read_browse_name()).Name
                axis = await node.get_child(f"{idx}:y")
                tbe = await axis.get_child(f"{idx}:TBE")
                seen[name] = sorted([(await t.read_browse_name()).Name for t in await tbe.get_children()])
            # the server's own nodes are where they were
            assert (await srv.nodes.server.read_browse_name()).Name == "Server"
            assert (await srv.get_node(ua.NodeId(ua.ObjectIds.Server)).read_browse_name()).Name == "Server"
            return seen
        finally:
            await srv.stop()

    seen = asyncio.run(go())
    assert sorted(seen) == sorted(machines)
    assert all(tasks == ["a", "a/Tolerance"] for tasks in seen.values())
