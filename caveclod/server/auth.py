"""Bearer-token authentication of the caveclod.v1.Lod methods (``--token-file``).

A server interceptor: calls to ``/caveclod.v1.Lod/*`` must carry metadata
``authorization: Bearer <token>`` with one of the accepted tokens, or end
with UNAUTHENTICATED. Health checks and reflection stay open, so that load
balancers and probes need no secret.
"""

from __future__ import annotations

import hmac
from pathlib import Path

import grpc
import grpc.aio

from ..errors import InputError

PROTECTED = "/caveclod.v1.Lod/"


def read_tokens(path) -> tuple[str, ...]:
    """Accepted tokens: one per line of the file; blank lines and ``#`` comments skipped.

    Several lines let an operator rotate tokens without a restart gap.
    """
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise InputError(f"cannot read --token-file {path}: {exc.strerror}") from None
    tokens = tuple(t.strip() for t in lines if t.strip() and not t.strip().startswith("#"))
    if not tokens:
        raise InputError(f"--token-file {path} holds no token; put one token per line")
    return tokens


class BearerTokenInterceptor(grpc.aio.ServerInterceptor):
    """Refuses calls to the Lod service without an accepted bearer token."""

    def __init__(self, tokens):
        self._tokens = [t.encode() for t in tokens]

    async def intercept_service(self, continuation, details):
        if not details.method.startswith(PROTECTED):
            return await continuation(details)
        header = dict(details.invocation_metadata).get("authorization", "")
        scheme, _, token = header.partition(" ")
        # compare_digest against every token: no timing hint of a near miss
        if scheme.lower() == "bearer" and any([hmac.compare_digest(token.encode(), t) for t in self._tokens]):
            return await continuation(details)
        handler = await continuation(details)
        return _refusal(handler, "missing authorization metadata" if not header else "the bearer token is not accepted")


def _refusal(handler, why: str):
    message = f"{why}; send metadata 'authorization: Bearer <token>' with a token the server accepts"

    async def refuse(request, context):
        await context.abort(grpc.StatusCode.UNAUTHENTICATED, message)

    if handler is None:
        return None
    if handler.request_streaming and handler.response_streaming:
        return grpc.stream_stream_rpc_method_handler(refuse, handler.request_deserializer, handler.response_serializer)
    return grpc.unary_unary_rpc_method_handler(refuse, handler.request_deserializer, handler.response_serializer)
