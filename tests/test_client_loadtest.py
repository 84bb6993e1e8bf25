"""`caveclod loadtest` against an in-process server: figures, progress, exit status."""

from __future__ import annotations

import json

from caveclod import cli


def test_loadtest_reports_json_and_exits_0(server, tmp_path, capsys):
    plot = tmp_path / "latency.png"
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "3", "--cameras", "2",
                       "--duration", "2", "--rate", "20", "--trajectory", "circle", "--json",
                       "--plot", str(plot), "--cache-dir", str(tmp_path / "cache")])
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert status == 0, report
    assert report["sessions"] == 3 and report["divergences"] == 0 and report["errors"] == {}
    assert report["resumes"] == 0 and report["failovers"] == 0
    assert report["frames"] >= 3 * 20 and report["frames_per_second"] > 0
    assert set(report["latency_ms"]) == {"p50", "p95", "p99", "max"}
    assert 0 < report["latency_ms"]["p50"] <= report["latency_ms"]["p99"] <= report["latency_ms"]["max"]
    assert 0.8 * 3 * 2 * 40 <= report["poses_sent"] <= 3 * 2 * 40        # ticks missed while opening are skipped
    assert report["bytes_per_frame"] > 0 and report["bytes_per_changed_triangle"] > 12
    assert "loadtest:" in err and "latency p50" in err              # the progress line
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_loadtest_counts_errors_and_exits_1(make_server, tmp_path, capsys):
    server = make_server(max_sessions=1)
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "3", "--duration", "1",
                       "--json", "--cache-dir", str(tmp_path)])
    report = json.loads(capsys.readouterr().out)
    assert status == 1
    assert report["errors"] == {"RESOURCE_EXHAUSTED": 2}


def test_loadtest_of_an_unknown_mesh_or_no_server_is_one_line(server, capsys):
    assert cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--mesh", "nope", "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "terrain" in err and err.count("\n") == 1
    server.stop(grace=0)
    assert cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--duration", "1"]) == 1
    err = capsys.readouterr().err
    assert "UNAVAILABLE" in err and err.count("\n") == 1
