"""`caveclod loadtest` against an in-process server: figures, progress, exit status."""

from __future__ import annotations

import json

import pytest

from caveclod import cli, opstream


@pytest.mark.parametrize("encoding, transport, decoder", [("ops", "h2", "auto"), ("raw", "h2", "auto"),
                                                        ("ops", "grpc", "numpy")])
def test_loadtest_reports_json_and_exits_0(server, tmp_path, capsys, encoding, transport, decoder):
    plot = tmp_path / "latency.png"
    no_prune = ["--no-prune", "--strict-bound"] if encoding == "raw" else []
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "3", "--cameras", "2",
                       "--duration", "2", "--rate", "20", "--trajectory", "circle", "--json",
                       "--plot", str(plot), "--cache-dir", str(tmp_path / "cache"), "--frame-encoding", encoding,
                       "--transport", transport, "--decoder", decoder] + no_prune)
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert status == 0, report
    assert report["prune"] == (not no_prune) and report["transport"] == transport
    assert report["strict_bound"] == bool(no_prune)
    # auto: the compiled decoder, numba being installed with the tests; the process's thin
    # clients decode with numpy again once the load test is over.
    assert report["decoder"] == ("compiled" if decoder == "auto" else "numpy") and opstream._compiled is None
    assert report["sessions"] == 3 and report["divergences"] == 0 and report["errors"] == {}
    assert report["resumes"] == 0 and report["failovers"] == 0
    assert report["frames"] >= 3 * 20 and report["frames_per_second"] > 0
    assert set(report["latency_ms"]) == {"p50", "p95", "p99", "max"}
    assert 0 < report["latency_ms"]["p50"] <= report["latency_ms"]["p99"] <= report["latency_ms"]["max"]
    assert 0.8 * 3 * 2 * 40 <= report["poses_sent"] <= 3 * 2 * 40        # ticks missed while opening are skipped
    assert report["frame_encoding"] == encoding and report["bytes_per_frame"] > 0
    # RAW costs at least 12 bytes a triangle (its three indices); op streams well under that.
    assert report["bytes_per_changed_triangle"] > 12 if encoding == "raw" else report["bytes_per_changed_triangle"] < 9
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


def test_loadtest_in_cache_mode_reports_what_the_cache_did(server, tmp_path, capsys):
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "2", "--cameras", "2",
                       "--duration", "2", "--rate", "20", "--trajectory", "rotate", "--json",
                       "--cache-vertices", "1200", "--cache-strategy", "lru_pq", "--cache-dir", str(tmp_path)])
    report = json.loads(capsys.readouterr().out)
    assert status == 0, report
    assert report["divergences"] == 0 and report["errors"] == {} and report["bad_frames"] == 0
    assert report["cache_vertices"] == 1200 and report["cache_strategy"] == "lru_pq"
    assert report["vertices_inserted"] > 0 and report["vertex_bytes_per_frame"] > 0
    assert 0.0 <= report["cache_hit_rate"] <= 1.0
    assert not list(tmp_path.iterdir()), "cache mode downloads no vertex buffer"


def test_loadtest_cache_flags_are_checked(server, capsys):
    target = ["loadtest", "--target", f"127.0.0.1:{server.port}", "--duration", "1"]
    assert cli.main(target + ["--cache-strategy", "fa"]) == 2
    assert "need --cache-vertices" in capsys.readouterr().err
    assert cli.main(target + ["--cache-vertices", "0"]) == 2
    assert "at least 1" in capsys.readouterr().err
    assert cli.main(target + ["--cache-vertices", "3", "--json"]) == 1        # below the base mesh: refused
    out, err = capsys.readouterr()
    assert json.loads(out)["errors"] == {"INVALID_ARGUMENT": 1}
    assert "ask for at least" in err


def test_shard_processes_run_with_the_switches_of_the_load_test():
    from caveclod.client.loadtest import _argv
    args = cli._parser().parse_args(["loadtest", "--target", "127.0.0.1:1", "--no-prune", "--strict-bound"])
    shard = cli._parser().parse_args(["loadtest", *_argv(args)])
    assert shard.no_prune and shard.strict_bound
    plain = cli._parser().parse_args(["loadtest", *_argv(cli._parser().parse_args(["loadtest", "--target", "h:1"]))])
    assert not plain.no_prune and not plain.strict_bound


def test_loadtest_in_several_processes_merges_their_figures(server, tmp_path, capsys):
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "4", "--duration", "2",
                       "--rate", "20", "--processes", "2", "--connections", "2", "--json", "--samples",
                       "--cache-dir", str(tmp_path)])
    report = json.loads(capsys.readouterr().out)
    assert status == 0, report
    assert report["processes"] == 2 and report["sessions"] == 4 and report["divergences"] == 0
    # Every session's frames and poses are counted once, from both processes.
    assert 0.8 * 4 * 40 <= report["poses_sent"] <= 4 * 40
    assert report["frames"] >= 4 * 20 and len(report["latencies_ms"]) == report["poses_timed"] > 0
    assert report["client_cpu_ms_per_frame"] > 0
    assert server.metrics.total("frames") >= report["frames"]


def test_a_run_in_which_no_frame_came_exits_1_saying_so(monkeypatch, capsys):
    """A sweep saw a load test count 1,444 poses sent and no frame at all (a stalled server) and
    exit 0, as if it had measured something; every session's first frame is its keyframe, so
    none is a failure, said in one line."""
    from caveclod.client import loadtest

    async def stalled(args):
        return {"frames": 0, "keyframes": 0, "poses_sent": 1444, "divergences": 0, "errors": {},
                "latencies_ms": []}
    monkeypatch.setattr(loadtest, "run", stalled)
    assert cli.main(["loadtest", "--target", "127.0.0.1:1", "--duration", "2", "--json"]) == 1
    err = capsys.readouterr().err
    assert "no frame came in 2 s (1,444 poses sent)" in err and err.count("\n") == 1


@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_a_run_the_server_refused_names_the_refusal_not_a_silent_server(server, tmp_path, capsys, transport):
    """Five cameras against a server allowing four: refused at once, but the last line said "the
    server did not answer; check its log and load", and over h2 the run waited out its duration."""
    import time
    if transport == "h2":
        pytest.importorskip("hpack", reason="the hpack library (the loadtest extra) is not installed")
    t0 = time.perf_counter()
    status = cli.main(["loadtest", "--target", f"127.0.0.1:{server.port}", "--sessions", "2", "--cameras", "5",
                       "--duration", "60", "--transport", transport, "--json", "--cache-dir", str(tmp_path)])
    took = time.perf_counter() - t0
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert status == 1 and report["frames"] == 0 and report["errors"] == {"INVALID_ARGUMENT": 2}
    assert "every session ended with an error (2 INVALID_ARGUMENT" in err.splitlines()[-1]
    assert took < 40, f"the refused run waited {took:.0f} s of its 60"
