"""Generated caveclod.v1 stubs (``make protos`` regenerates them from protos/).

``caveclod_pb2`` (messages), ``caveclod_pb2_grpc`` (``LodStub``,
``LodServicer``). Committed, so that a fresh clone and the thin client need
no code generator; ``tests/test_stubs.py`` fails when they are stale.
"""
