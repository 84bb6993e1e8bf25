"""How the gRPC handler's reader tells a broken stream from a server bug.

A sweep that killed 96 clients with SIGKILL while frames were being written
found 6 sessions ended as INTERNAL ("session.error", the session discarded):
grpc.aio's write to a dead peer raised its ExecuteBatchError, which is not a
grpc.RpcError, and the reader took it for a fault in making frames. A write
failing is the stream's end; the session stays resumable.
"""

from __future__ import annotations

import asyncio

import grpc

from caveclod.server import service
from caveclod.server.session import End
from caveclod.v1 import caveclod_pb2 as pb


class _PeerGone(Exception):
    """Stands for grpc.aio's cygrpc ExecuteBatchError: an Exception, not a grpc.RpcError."""


class _Context:
    def __init__(self, error: Exception | None):
        self.error, self.written = error, []

    async def write(self, message):
        if self.error is not None:
            raise self.error
        self.written.append(message)

    def done(self) -> bool:
        return False


class _Session:
    """What _read and _Stream ask of a session: a cheap frame due at once, every time."""

    cheap = True

    def __init__(self, fail_making: bool = False):
        self.ended: list[End] = []
        self.fail_making = fail_making

    def accept(self, msg, generation, wake=True) -> bool:
        return True

    def poll(self, generation, stopped):
        return 0.0

    def make_frame(self, generation):
        if self.fail_making:
            raise ValueError("a bug while making the frame")
        return [b"frame"]

    def finish(self, end, generation=None):
        self.ended.append(end)

    def describe(self) -> dict:
        return {"session": "test"}


class _Metrics:
    def frame_sent(self, size):
        pass


async def _messages():
    yield pb.ClientMessage(pose=pb.CameraPose())


def _run_reader(session, context) -> None:
    async def scenario():
        stream = service._Stream(session, 1, context, None, _Metrics())
        await asyncio.wait_for(service._read(_messages(), stream), 10)
    asyncio.run(scenario())


def test_a_write_to_a_peer_that_died_is_a_broken_stream_not_a_server_bug():
    session = _Session()
    _run_reader(session, _Context(_PeerGone("Failed \"execute_batch\"")))
    assert not any(end.code == grpc.StatusCode.INTERNAL for end in session.ended), session.ended


def test_a_fault_while_making_a_frame_is_still_a_server_bug():
    session = _Session(fail_making=True)
    _run_reader(session, _Context(None))
    assert [end.code for end in session.ended] == [grpc.StatusCode.INTERNAL]


def test_send_raises_stream_broke_only_for_what_is_not_grpcs_own():
    async def write_with(error):
        try:
            await service.send(_Context(error), b"x")
        except Exception as exc:        # noqa: BLE001 - the type is what is checked
            return type(exc)
        return None
    assert asyncio.run(write_with(_PeerGone("gone"))) is service.StreamBroke
    assert asyncio.run(write_with(None)) is None
    rpc_error = grpc.RpcError()
    assert asyncio.run(write_with(rpc_error)) is grpc.RpcError
