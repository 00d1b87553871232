"""The tiers' Publisher on a real server: unchanged values are not stored again, client writes
in between are seen.

A tier republishes every value each scan; storing only the values that moved keeps each node's
timestamps at its last change and spares the scan most of the address-space writes. The
comparison is against the address space, so a client's accepted write is never mistaken for the
tier's own value.
"""

from __future__ import annotations

from typing import Any

from asyncua import ua

from helpers import ROOT, free_port, secure, server_security
from tanklab.config import load_site
from tanklab.tags import Tag, plc_tags
from tanklab_io.ua import MethodHandler, WriteHandler
from tanklab_io.ua_security import start_tier_server

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")


async def _nothing(*_: Any) -> list[ua.Variant] | ua.StatusCode:
    return ua.StatusCode(ua.StatusCodes.Good)


def _accept(tag: Tag, value: Any) -> ua.StatusCode | None:
    return None


async def test_publish_stores_only_changes_and_sees_client_writes() -> None:
    tags = plc_tags(SITE)
    methods: dict[str, MethodHandler] = {t.path: _nothing for t in tags if t.kind == "method"}
    writes: dict[str, WriteHandler] = {t.path: _accept for t in tags if t.kind == "variable" and t.writable}
    url = f"opc.tcp://127.0.0.1:{free_port()}/tanklab/plc"
    tier = await start_tier_server(
        "plc",
        url=url,
        name="publisher test",
        security=server_security(),
        tags=tags,
        writes=writes,
        methods=methods,
    )
    pub, sp, pv = tier.publisher, tier.nodes["PLC.LIC1.SP"].nodeid, tier.nodes["PLC.LIC1.PV"].nodeid
    try:
        await pub.publish({"PLC.LIC1.SP": 0.4, "PLC.LIC1.PV": 0.1})
        first = tier.server.read_attribute_value(sp)
        await pub.publish({"PLC.LIC1.SP": 0.4, "PLC.LIC1.PV": 0.2})
        again = tier.server.read_attribute_value(sp)
        assert again.Value.Value == 0.4
        assert again.SourceTimestamp == first.SourceTimestamp  # unchanged: not stored again
        assert tier.server.read_attribute_value(pv).Value.Value == 0.2

        # An operator's write is stored by the guard; the tier's next publish of its own value
        # (say the program refused to apply it) must still put its value back.
        async with await secure(url, "operator") as client:
            await client.get_node(sp).write_value(ua.Variant(0.45, ua.VariantType.Double))
            assert await client.get_node(sp).read_value() == 0.45
            await pub.publish({"PLC.LIC1.SP": 0.4})
            assert await client.get_node(sp).read_value() == 0.4
    finally:
        await tier.server.stop()
