"""``caveclod health``: ask a server's grpc.health.v1 service whether it serves.

A container's HEALTHCHECK (deploy/Dockerfile) runs it every few seconds, so
it imports grpc and the health stubs only, not the server. Kubernetes asks
the same service natively (``grpc:`` probes, deploy/k8s/).

Exit status: 0 when the service is SERVING; 1 when it is not (NOT_SERVING
while a server drains, unknown service, no answer within the timeout, no
connection); the reason goes to stderr as one line.
"""

from __future__ import annotations

import math

import sys

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc

def check(target: str, service: str = "", timeout: float = 2.0, tls_ca: bytes | None = None) -> str:
    """The serving status name (SERVING, NOT_SERVING, ...) of ``service`` at ``target``; raises grpc.RpcError."""
    channel = grpc.insecure_channel(target) if tls_ca is None \
        else grpc.secure_channel(target, grpc.ssl_channel_credentials(root_certificates=tls_ca))
    with channel:
        reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(service=service),
                                                          timeout=timeout)
    return health_pb2.HealthCheckResponse.ServingStatus.Name(reply.status)


def main(args) -> int:
    """``caveclod health`` (see ``caveclod health --help``); returns the exit status."""
    from ..errors import InputError
    if not 0 < args.timeout < math.inf:
        raise InputError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    port = args.target.rpartition(":")[2]
    if port.isdigit() and not 0 < int(port) <= 65535:
        # gRPC took port 99999 modulo 65536 (34463) and connected there.
        raise InputError(f"the target {args.target}'s port must be from 1 to 65535")
    tls_ca = None
    if args.tls_ca:
        try:
            with open(args.tls_ca, "rb") as fh:
                tls_ca = fh.read()
        except OSError as exc:
            raise InputError(f"cannot read --tls-ca {args.tls_ca}: {exc.strerror}") from None
    try:
        status = check(args.target, args.service, args.timeout, tls_ca)
    except grpc.RpcError as exc:
        print(f"caveclod health: {args.target} {args.service or '(server)'}: {exc.code().name}: {exc.details()}",
              file=sys.stderr)
        return 1
    if status != "SERVING":
        print(f"caveclod health: {args.target} {args.service or '(server)'}: {status}", file=sys.stderr)
        return 1
    return 0
