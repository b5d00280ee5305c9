"""A minimal Foxglove WebSocket protocol client (``foxglove.sdk.v1`` = ``foxglove.websocket.v1``) for the tests, on aiohttp.

It speaks the protocol as the Foxglove app does: reads ``serverInfo`` and ``advertise``,
sends ``subscribe`` / ``fetchAsset``, and decodes the binary frames (message data: opcode 1,
subscription id u32, log time u64, payload; asset response: opcode 4).  Protobuf payloads are
decoded with the FileDescriptorSet the server advertised (the ``protobuf`` package), JSON ones
with ``json``.
"""
from __future__ import annotations

import asyncio
import base64
import json
import struct

import aiohttp

#: the name the Foxglove SDK's server gives the protocol: message for message ``foxglove.websocket.v1``,
#: renamed; the SDK's server accepts only this name (droid-foxglove's token gate accepts both)
SUBPROTOCOL = "foxglove.sdk.v1"
OLD_SUBPROTOCOL = "foxglove.websocket.v1"
OP_MESSAGE_DATA = 0x01
OP_FETCH_ASSET_RESPONSE = 0x04


def protobuf_class(schema_name: str, schema_b64: str):
    """The message class of ``schema_name`` from an advertised base64 FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


class FoxgloveClient:
    def __init__(self, ws) -> None:
        self.ws = ws
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}  # channel id -> advertised channel
        self.statuses: list[dict] = []

    async def read_handshake(self, timeout_s: float = 10.0, want_channels: int = 1) -> None:
        """Until serverInfo and at least ``want_channels`` advertised channels arrived."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while self.server_info is None or len(self.channels) < want_channels:
            msg = await self.ws.receive(timeout=max(0.01, end - loop.time()))
            self._text(msg)

    def _text(self, msg) -> None:
        if msg.type != aiohttp.WSMsgType.TEXT:
            if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                raise ConnectionError(f"closed: {msg}")
            return
        m = json.loads(msg.data)
        if m["op"] == "serverInfo":
            self.server_info = m
        elif m["op"] == "advertise":
            for ch in m["channels"]:
                self.channels[ch["id"]] = ch
        elif m["op"] == "status":
            self.statuses.append(m)

    async def subscribe(self, channel_ids) -> dict[int, int]:
        subs = {cid: i + 1 for i, cid in enumerate(channel_ids)}
        await self.ws.send_str(json.dumps({"op": "subscribe",
                                           "subscriptions": [{"id": s, "channelId": c} for c, s in subs.items()]}))
        return subs

    def decode(self, ch: dict, payload: bytes):
        if ch["encoding"] == "json":
            return json.loads(payload)
        if ch["encoding"] == "protobuf":
            cls = ch.setdefault("_cls", protobuf_class(ch["schemaName"], ch["schema"]))
            return cls.FromString(payload)
        raise AssertionError(f"unexpected encoding {ch['encoding']}")

    async def one_of_each(self, channel_ids, timeout_s: float = 15.0) -> dict[int, tuple[int, object]]:
        """Subscribe to ``channel_ids`` and return {channel id: (log time ns, decoded message)}, one each."""
        subs = await self.subscribe(channel_ids)
        by_sub = {s: c for c, s in subs.items()}
        got: dict[int, tuple[int, object]] = {}
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while len(got) < len(subs):
            msg = await self.ws.receive(timeout=max(0.01, end - loop.time()))
            if msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == OP_MESSAGE_DATA:
                sub_id, log_time = struct.unpack_from("<IQ", msg.data, 1)
                cid = by_sub[sub_id]
                if cid not in got:
                    got[cid] = (log_time, self.decode(self.channels[cid], msg.data[13:]))
            else:
                self._text(msg)
        return got

    async def fetch_asset(self, uri: str, request_id: int, timeout_s: float = 10.0) -> tuple[int, bytes, str]:
        """(status 0 ok / 1 error, data, error message) of one asset."""
        await self.ws.send_str(json.dumps({"op": "fetchAsset", "uri": uri, "requestId": request_id}))
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while True:
            msg = await self.ws.receive(timeout=max(0.01, end - loop.time()))
            if msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == OP_FETCH_ASSET_RESPONSE:
                rid, status, n = struct.unpack_from("<IBI", msg.data, 1)
                if rid == request_id:
                    err = msg.data[10:10 + n].decode()
                    return status, bytes(msg.data[10 + n:]), err
            else:
                self._text(msg)
