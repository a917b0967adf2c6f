"""A Foxglove websocket client for the tests, written from the protocol: the server's
``advertise`` names its channels, the client ``subscribe``s to some by id, and each message
comes as a binary frame: opcode 1, the subscription id (uint32 LE), the log time (uint64 LE,
ns), the payload (here JSON).

The client offers both subprotocols Foxglove offers: ``foxglove.websocket.v1`` (the original
ws-protocol) and ``foxglove.sdk.v1``, its successor, which foxglove-sdk's server requires
(0.30 selects it and refuses a client that offers only the first). The messages used here
are the same in both."""

from __future__ import annotations

import asyncio
import json
import struct
import sys
from dataclasses import dataclass, field
from typing import Any

from websockets.asyncio.client import connect

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
MESSAGE_DATA = 0x01
_HEADER = struct.Struct("<BIQ")


@dataclass
class Received:
    """What the client saw: the advertised channels by topic, and per topic the messages
    (log time, raw payload) in arrival order."""

    subprotocol: str | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)

    def json(self, topic: str) -> list[tuple[int, Any]]:
        return [(t, json.loads(data)) for t, data in self.messages.get(topic, [])]


async def listen(
    url: str,
    topics: set[str],
    received: Received,
    subscribed: asyncio.Event,
    required: set[str] | None = None,
    headers: dict[str, str] | None = None,
) -> None:
    """Connect, subscribe to ``topics`` as they are advertised (``subscribed`` is set once
    all of ``required``, default all of them, are), and collect into ``received`` until
    cancelled. ``headers``: the handshake's own (the viewer's ``Authorization``)."""
    required = topics if required is None else required
    offered: Any = list(SUBPROTOCOLS)
    async with connect(url, subprotocols=offered, additional_headers=headers) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        received.subprotocol = ws.subprotocol
        by_subscription: dict[int, str] = {}
        next_id = 0
        async for frame in ws:
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "serverInfo":
                    received.server_info = message
                elif message["op"] == "advertise":
                    wanted = []
                    for channel in message["channels"]:
                        received.channels[channel["topic"]] = channel
                        if channel["topic"] in topics:
                            wanted.append({"id": next_id, "channelId": channel["id"]})
                            by_subscription[next_id] = channel["topic"]
                            next_id += 1
                    if wanted:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))
                    if required <= set(by_subscription.values()):
                        subscribed.set()
                continue
            if frame[0] != MESSAGE_DATA:
                continue
            _, subscription, log_ns = _HEADER.unpack_from(frame)
            topic = by_subscription[subscription]
            received.messages.setdefault(topic, []).append((log_ns, bytes(frame[_HEADER.size :])))


def main(argv: list[str]) -> None:
    """``python -m tests.server.link.foxglove_client URL TOPIC...``: listen (in a process of
    its own, so that a bench's client takes no GIL from what it measures) until standard
    input closes, then print the count of messages per topic as JSON."""
    url, topics = argv[0], set(argv[1:])

    async def run() -> None:
        received = Received()
        subscribed = asyncio.Event()
        first = {"/tf", "/events", "/scene", "/robot_description"} & topics
        task = asyncio.create_task(listen(url, topics, received, subscribed, required=first))
        await asyncio.wait_for(subscribed.wait(), 30.0)
        print("subscribed", flush=True)
        await asyncio.to_thread(sys.stdin.read)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        print(json.dumps({t: len(m) for t, m in received.messages.items()}), flush=True)

    asyncio.run(run())


if __name__ == "__main__":
    main(sys.argv[1:])
