"""A Python WebSocket client of caveclod.v1 (what the browser page does), for the web tests."""

from __future__ import annotations

import aiohttp

from caveclod.client import SessionProtocol
from caveclod.server import web
from caveclod.v1 import caveclod_pb2 as pb

from service import WAIT

OPTIONS = {"width": 640, "height": 360, "fov_y": None, "tolerance_px": 1.0, "cull": None, "backface": None,
           "max_ops": None, "max_faces": None}


class WsClient:
    """A SessionProtocol over an aiohttp WebSocket: what the browser page does, in Python."""

    def __init__(self, ws, protocol: SessionProtocol):
        self.ws, self.protocol = ws, protocol
        self.status: pb.Status | None = None

    async def send(self, msg: pb.ClientMessage) -> None:
        await self.ws.send_bytes(msg.SerializeToString())

    async def receive(self):
        """The next frame applied (acks and keyframe requests sent back), or None at the end (status kept)."""
        while True:
            msg = await self.ws.receive(timeout=WAIT)
            if msg.type != aiohttp.WSMsgType.BINARY:
                return None
            server_msg = pb.ServerMessage.FromString(msg.data)
            if server_msg.WhichOneof("kind") == "status":
                self.status = server_msg.status
                continue
            replies, update = self.protocol.receive(server_msg)
            for reply in replies:
                await self.send(reply)
            if update is not None:
                return update


async def ws_session(url: str, fly, *, protocols=(web.SUBPROTOCOL,), query="", mesh="terrain", token_protocol=None,
                     protocol=None):
    """Open a session over WebSocket and run ``fly(client)``; the client (with its final status)."""
    protocol = protocol or SessionProtocol(mesh, 1, OPTIONS, frame_encoding="raw")
    offered = list(protocols) + ([web.TOKEN_SUBPROTOCOL + token_protocol] if token_protocol else [])
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url + query, protocols=offered) as ws:
            client = WsClient(ws, protocol)
            client.subprotocol = ws.protocol
            await client.send(protocol.open_message())
            await fly(client)
            while await client.receive() is not None:
                pass
            client.close_code = ws.close_code
            return client


