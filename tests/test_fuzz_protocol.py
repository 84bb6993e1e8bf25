"""The protocol fuzzer (tests/fuzzprotocol.py), briefly and with fixed seeds: a real
`caveclod serve` keeps the contract, and a server with a bug does not."""

from __future__ import annotations

import grpc

from fuzzing import Budget, FuzzReport
from fuzzprotocol import fuzz_protocol, run_against_serve


def test_caveclod_serve_keeps_the_contract_under_fuzzing(terrain_path):
    report = run_against_serve([terrain_path], Budget(seconds=6.0), seed=17)
    report.assert_clean()
    # Every kind of end was seen: served, refused, a mesh not found, our own cancels.
    for code in ("OK", "INVALID_ARGUMENT", "NOT_FOUND", "CANCELLED"):
        assert report.outcomes.get(code, 0) > 0, report.as_json()
    assert report.units["messages"] >= 1000, report.as_json()
    assert report.units["honest_frames"] > 0, report.as_json()


def test_the_fuzzer_finds_a_server_bug(make_server, monkeypatch):
    """A pose check that raises (a server bug) ends streams with INTERNAL: "status" findings."""
    from caveclod.server.session import Session

    def broken_pose_check(self, pose):
        raise RuntimeError("the pose check broke")

    server = make_server(resume_ttl=1, max_sessions=200, metrics_port=0, metrics_host="127.0.0.1")
    monkeypatch.setattr(Session, "_accept_pose", broken_pose_check)
    report = fuzz_protocol(server.port, Budget(cases=150, seconds=8.0), seed=3, report=FuzzReport("broken"),
                           metrics_port=server.metrics_port, concurrency=8, honest=False)
    counts = report.finding_counts()
    assert counts["status"] > 0, report.as_json()
    assert report.outcomes.get(grpc.StatusCode.INTERNAL.name, 0) == counts["status"]
    assert counts["leak"] == 0 and counts["hang"] == 0, report.as_json()


def test_the_command_line_writes_its_report(terrain_path, tmp_path):
    """What benchmarks/fuzz.py runs: a few cases, the report as JSON on stdout and in --out."""
    import json

    from fuzzprotocol import main
    out = tmp_path / "protocol.json"
    assert main([str(terrain_path), "--cases", "30", "--seconds", "30", "--seed", "4", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["cases"] == 30 and report["units"]["messages"] > 0 and report["fuzzer_error"] == ""
    assert sum(report["findings"].values()) == 0 and report["messages_per_second"] > 0


def test_the_websocket_front_keeps_the_contract_under_fuzzing(terrain_path):
    """The same cases over WebSocket (serve --web-port): the same statuses, each with its close code."""
    report = run_against_serve([terrain_path], Budget(seconds=6.0), seed=23, websocket=True)
    report.assert_clean()
    for code in ("OK", "INVALID_ARGUMENT", "NOT_FOUND", "CANCELLED"):
        assert report.outcomes.get(code, 0) > 0, report.as_json()
    assert report.units["messages"] >= 500, report.as_json()
