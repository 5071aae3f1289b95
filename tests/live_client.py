"""A Foxglove WebSocket client for the tests of the live view: subscribes to every
advertised channel and decodes the binary message frames and their JSON payloads."""

from __future__ import annotations

import asyncio
import json
import struct
import time

#: the Foxglove WebSocket protocol's binary opcode of a message frame
MESSAGE_DATA = 0x01


async def listen(port: int, seconds: float) -> tuple[list, dict[str, list]]:
    """Connect, subscribe to every channel, collect ``{topic: [payload, ...]}`` until the
    server closes the connection or ``seconds`` pass."""
    import websockets

    channels: list = []
    got: dict[str, list] = {}
    by_sub: dict[int, str] = {}
    async with websockets.connect(f"ws://127.0.0.1:{port}",
                                  subprotocols=["foxglove.sdk.v1",
                                                "foxglove.websocket.v1"]) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), max(0.01, end - time.monotonic()))
            except (asyncio.TimeoutError, websockets.ConnectionClosed):
                break   # the demo is over: the view stopped with it
            if isinstance(frame, str):
                doc = json.loads(frame)
                if doc.get("op") == "advertise":
                    channels += doc["channels"]
                    subs = []
                    for c in doc["channels"]:
                        by_sub[c["id"]] = c["topic"]
                        subs.append({"id": c["id"], "channelId": c["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif frame and frame[0] == MESSAGE_DATA:
                sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                got.setdefault(by_sub[sub_id], []).append(json.loads(frame[13:]))
    return channels, got


def connect_when_up(port: int, deadline: float, seconds: float):
    while True:
        try:
            return asyncio.run(listen(port, seconds))
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
