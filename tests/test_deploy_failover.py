"""Scale-out on loopback: two `caveclod serve` replicas behind a real nginx
configured from deploy/nginx/caveclod.conf.template, viewers flying through
it while one replica is killed (SIGKILL) or drained (SIGTERM).

Every viewer must carry on through the balancer by itself (the client
library's failover), with zero divergences; the viewers of the lost replica
start a fresh session on the other one, keep their vertex buffer (offered by
hash: nothing downloaded again) and continue from a keyframe. Each test
prints every viewer's gap, in milliseconds and in frames missed at 30 Hz
(`pytest -s` shows them; deploy/README.md gives a run's figures).

nginx comes from the system (.ci/run installs Debian's nginx-light); where
it is missing these tests are skipped. Processes are stopped by pid in
``finally`` blocks; everything listens on 127.0.0.1.
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
from pathlib import Path

import pytest

from failover import Balancer, Replica, close_viewers, nginx_binary, open_viewers
from service import stop_process

NGINX = nginx_binary()
pytestmark = pytest.mark.requires_tool("nginx")

BEFORE, AFTER = 2.0, 5.0          # seconds of flight before the replica goes, and after
DRAIN = 1.5                       # --drain-seconds of the replicas


def _fly(viewers, lo, hi, until):
    threads = [threading.Thread(target=v.fly, args=(until, lo, hi), daemon=True) for v in viewers]
    for t in threads:
        t.start()
    return threads


def _report(kind: str, viewers, victim, since: float) -> list[dict]:
    rows = []
    for v in viewers:
        gap_ms, gap_frames = v.gap(since)
        rows.append({"viewer": v.index, "moved": victim.holds(v.frames[0][2]) if v.frames else None,
                     "gap_ms": round(gap_ms), "gap_frames": gap_frames, "frames": len(v.frames),
                     "failovers": v.session.protocol.failovers, "resumes": v.session.protocol.resumes,
                     "divergences": v.session.protocol.divergences, "bad_frames": v.session.protocol.bad_frames})
    print(f"\n{kind}: viewer, on the lost replica, gap ms, frames missed at 30 Hz, frames, failovers")
    for r in rows:
        print(f"  {r['viewer']:2d} {'moved' if r['moved'] else 'stayed':6s} {r['gap_ms']:5d} ms {r['gap_frames']:3d} "
              f"frames  {r['frames']:4d}  failovers {r['failovers']}")
    return rows


def _check(viewers, victim, survivor, since: float, cache_dir: Path) -> None:
    errors = {v.index: repr(v.error) for v in viewers if v.error is not None}
    assert not errors, f"viewers stopped: {errors}"
    moved = [v for v in viewers if victim.holds(v.frames[0][2])]
    stayed = [v for v in viewers if v not in moved]
    assert moved and stayed
    for v in viewers:
        p = v.session.protocol
        assert p.divergences == 0 and p.bad_frames == 0, (v.index, p.divergences, p.bad_frames)
        after = [f for f in v.frames if f[0] > since]
        assert len(after) >= 30, f"viewer {v.index}: {len(after)} frames after the replica went"
        # Every frame applied in full follows the one before it, within its session.
        for (_, a, ta, _), (_, b, tb, _) in zip(v.frames, v.frames[1:]):
            assert b == a + 1 if ta == tb else b == 1, (v.index, a, b)
    for v in moved:
        p = v.session.protocol
        tokens = list(dict.fromkeys(f[2] for f in v.frames))
        assert len(tokens) == 2 and p.failovers == 1 and p.resumes == 0, (v.index, tokens, p.failovers, p.resumes)
        assert survivor.holds(tokens[1]), f"viewer {v.index}'s new session is not on the surviving replica"
        first = next(f for f in v.frames if f[2] == tokens[1])
        assert first[1] == 1 and first[3], "the fresh session starts from a keyframe (frame 1)"
        assert v.session.info.vertex_buffer_cached, "the vertex buffer was downloaded again"
        assert not v.session.info.resumed
        gap_ms, _ = v.gap(since)
        assert gap_ms < 5000, f"viewer {v.index} waited {gap_ms:.0f} ms for the other replica"
    for v in stayed:
        p = v.session.protocol
        assert p.failovers == 0 and len({f[2] for f in v.frames}) == 1, v.index
        gap_ms, _ = v.gap(since)
        assert gap_ms < 2000, f"viewer {v.index} on the surviving replica stalled {gap_ms:.0f} ms"
    assert len(list(cache_dir.iterdir())) == 1, "one vertex buffer, downloaded once, cached once"


def _run(terrain_path, tmp: Path, how: str, transport: str = "grpc") -> dict:
    """Two replicas, nginx, viewers on both; the busier replica is killed or drained mid-flight."""
    out: dict = {}
    replicas, balancer, viewers = [], None, []
    try:
        for name in ("a", "b"):
            replicas.append(Replica(terrain_path, tmp, name, "--drain-seconds", str(DRAIN), "--max-sessions", "16",
                                    "--transport", transport))
        balancer = Balancer(NGINX, replicas)
        cache = tmp / "cache"
        open_viewers(viewers, f"127.0.0.1:{balancer.port}", replicas, cache, per_replica=2)
        lo = viewers[0].session.vertex_buffer.positions.min(0)
        hi = viewers[0].session.vertex_buffer.positions.max(0)
        # The replica with more sessions goes away.
        victim = max(replicas, key=lambda r: sum(r.holds(v.session.protocol.token) for v in viewers))
        survivor = next(r for r in replicas if r is not victim)
        t0 = time.monotonic()
        threads = _fly(viewers, lo, hi, t0 + BEFORE + AFTER)
        time.sleep(BEFORE)
        since = time.monotonic()
        os.kill(victim.proc.pid, signal.SIGKILL if how == "kill" else signal.SIGTERM)
        for t in threads:
            t.join(BEFORE + AFTER + 30)
        assert not any(t.is_alive() for t in threads), "a viewer did not stop"
        out["rows"] = _report("SIGKILL" if how == "kill" else f"SIGTERM, --drain-seconds {DRAIN}", viewers,
                              victim, since)
        _check(viewers, victim, survivor, since, cache)
        assert victim.proc.wait(10) == (-signal.SIGKILL if how == "kill" else 0)   # a drain exits 0
        out.update(viewers=viewers, victim=victim, survivor=survivor, since=since)
        return out
    finally:
        close_viewers(viewers)
        if balancer is not None:
            time.sleep(0.2)                     # nginx logs a stream when it ends
            out["access_log"] = balancer.access_log()
            balancer.stop()
        for r in replicas:
            stop_process(r.proc)


def _moved(run: dict) -> list:
    return [v for v in run["viewers"] if run["victim"].holds(v.frames[0][2])]


# Both server transports behind nginx: its gRPC proxy is a strict HTTP/2 peer.
@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_a_killed_replica_s_viewers_carry_on_through_the_balancer(terrain_path, tmp_path, transport):
    run = _run(terrain_path, tmp_path, "kill", transport)
    # Each moved viewer's resume (its key) went to the surviving replica. nginx
    # found the dead one refusing connections and passed the stream on to the
    # next replica on the ring (its access log lists both).
    dead, alive = (f"127.0.0.1:{r.port}" for r in (run["victim"], run["survivor"]))
    log = [line for line in run["access_log"] if "/caveclod.v1.Lod/Session" in line]
    for v in _moved(run):
        key = v.session.protocol.affinity_key
        mine = [line for line in log if line.endswith(f"key={key}", 0, line.rindex(" t="))]
        assert len(mine) == 2 and f"upstream={dead} " in mine[0], (key, mine)
        assert re.search(rf"upstream=({re.escape(dead)}, )?{re.escape(alive)} key=", mine[1]), (key, mine)
    assert any(f"upstream={dead}, {alive} key=" in line for line in log), log


@pytest.mark.parametrize("transport", ["grpc", "h2"])
def test_a_draining_replica_s_viewers_move_when_their_sessions_end(terrain_path, tmp_path, transport):
    run = _run(terrain_path, tmp_path, "term", transport)
    for v in _moved(run):
        # The session went on through the drain on its replica (health said
        # NOT_SERVING, new sessions were refused), then moved.
        old = [t for t, _, token, _ in v.frames if token == v.frames[0][2] and t > run["since"]]
        assert old and old[-1] - run["since"] > DRAIN * 0.6, f"viewer {v.index}'s session ended before the drain did"
