"""A client of the Foxglove WebSocket protocol for the tests: it connects (retrying while the server starts),
subscribes to the advertised channels it is asked for, and decodes their messages with the mcap libraries'
protobuf decoder (the channel's advertised schema) or json."""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import threading
import time

import websockets
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # the protocol's binary opcode for a subscribed channel's message


async def watch(url: str, topics: set[str], until: float, received: dict[str, list]) -> None:
    """Connect (retrying while the companion starts), subscribe to `topics`, collect (log time s, message)."""
    while time.monotonic() < until:
        try:
            client = await websockets.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=2.0)
            break
        except (OSError, asyncio.TimeoutError, websockets.exceptions.InvalidHandshake):
            await asyncio.sleep(0.2)
    else:
        return
    decoders: dict[int, tuple[str, object]] = {}
    async with client:
        while time.monotonic() < until:
            try:
                message = await asyncio.wait_for(client.recv(), timeout=1.0)
            except asyncio.TimeoutError:
                continue
            except websockets.exceptions.ConnectionClosed:
                return  # the companion stopped its server at the end of the flight
            if isinstance(message, str):
                document = json.loads(message)
                if document.get("op") != "advertise":
                    continue
                subscriptions = []
                for channel in document["channels"]:
                    if channel["topic"] in topics:
                        ident = len(decoders) + 1
                        if channel["encoding"] == "json":
                            decode = json.loads
                        else:
                            schema = Schema(id=ident, name=channel["schemaName"], encoding=channel["schemaEncoding"],
                                            data=base64.b64decode(channel["schema"]))
                            decode = DecoderFactory().decoder_for(channel["encoding"], schema)
                        decoders[ident] = (channel["topic"], decode)
                        subscriptions.append({"id": ident, "channelId": channel["id"]})
                if subscriptions:
                    await client.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
            elif message[0] == MESSAGE_DATA:
                _, ident, log_time = struct.unpack_from("<BIQ", message)
                topic, decode = decoders[ident]
                received.setdefault(topic, []).append((log_time * 1e-9, decode(message[13:])))




class LiveClient:
    """watch() in a thread of its own: `start()`, then `join()`; `received` maps topic -> [(log time s, message)]."""

    def __init__(self, url: str, topics: set[str], timeout: float) -> None:
        self.received: dict[str, list] = {}
        self._thread = threading.Thread(target=asyncio.run, daemon=True,
                                        args=(watch(url, topics, time.monotonic() + timeout, self.received),))

    def start(self) -> "LiveClient":
        self._thread.start()
        return self

    def join(self, timeout: float = 10.0) -> None:
        self._thread.join(timeout)
