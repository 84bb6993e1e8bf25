"""The renderer over the real service: the GPU mirrors the client library, and
``caveclod render``, ``caveclod view`` and ``caveclod demo`` work end to end.

Servers listen on 127.0.0.1, port 0; processes are stopped by their pid.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from caveclod.client import Client
from caveclod.render.flight import fly, path_poses
from caveclod.render.renderer import BACKGROUND
from caveclod.render.session import SessionRenderer
from caveclod.render.window import FlyController
from caveclod.v1 import caveclod_pb2 as pb
from service import ROOT

SKY = np.round(np.array(BACKGROUND) * 255).astype(np.uint8)
TIMEOUT = 240


def not_blank(image: np.ndarray, min_fraction: float = 0.2) -> bool:
    """At least ``min_fraction`` of the pixels are not the sky, and they vary (shading, texture)."""
    image = np.asarray(image)[..., :3]
    ground = (np.abs(image.astype(int) - SKY).sum(axis=-1) > 12)
    return ground.mean() >= min_fraction and image[ground].std() > 3.0


def png(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def run_cli(*args, env=None, timeout=TIMEOUT, wrap=()):
    """Run ``python -m caveclod.cli ARGS`` (optionally under ``wrap``, e.g. xvfb-run) in its own
    process group; kill the group by its pid when it overruns. Returns CompletedProcess."""
    cmd = [*wrap, sys.executable, "-m", "caveclod.cli", *map(str, args)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, **(env or {})}, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


# -- the GPU buffers equal the client library's -------------------------------------------

def test_gpu_buffers_equal_the_client_library_after_every_frame(server, gl, tmp_path):
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", cameras=3, width=160, height=90) as s:
            view = SessionRenderer(s, 320, 180, ctx=gl)
            frames = 0
            for rec in fly(s, view, "flyover", 40, fps=10.0, draw=False, verify=True):
                frames += len(rec.frames)
                assert not view.mismatches()
                if rec.index == 20:             # a keyframe mid-flight: buffers emptied and refilled
                    s.request_keyframe()
            assert frames >= 40
            assert s.protocol.divergences == 0
            touched = sum(len(view.renderer.index_buffer(c, m)) for c in range(3) for m in range(4))
            assert touched > 0
            # What the GPU draws is what the client holds, triangle for triangle.
            for c in range(3):
                for m in range(4):
                    np.testing.assert_array_equal(view.renderer.index_buffer(c, m), s.buffer(c, m))
            view.release()


@pytest.mark.parametrize("morph_ms, speed", [(400, None), (800, 30.0)])
def test_geomorphs_through_a_session_run_on_path_time_and_mirror_the_display(server, gl, tmp_path, morph_ms, speed):
    """A flight with --morph-ms (and --morph-speed): morphs are under way between frames (on the path's
    clock, 0.1 s a frame here), the GPU holds the display buffers and the camera's moving positions, and
    once the morphs are over the GPU holds the client library's buffers exactly. At a speed, morphs are
    timed by their path on screen from the poses the renderer drew."""
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", cameras=2, width=160, height=90, tolerance_px=0.5,
                            morph_targets=True, frame_encoding="linked") as s:
            assert s.info.frame_encoding == pb.FRAME_ENCODING_OPS_LINKED     # what render and view ask for
            view = SessionRenderer(s, 320, 90, ctx=gl, morph_ms=morph_ms, morph_speed=speed)
            busy, spans = 0, set()
            for rec in fly(s, view, "flyover", 30, fps=10.0, verify=True):
                assert not view.mismatches()
                busy += sum(len(m.active) > 0 for m in view.morphs)
                spans.update(m.span for morphs in view.morphs for m in morphs.active.values())
                for c, morphs in enumerate(view.morphs):
                    np.testing.assert_array_equal(view.renderer.camera_positions(c),
                                                  morphs.drawn_positions(rec.t).astype(np.float32))
            assert busy >= 10, "morphs must be under way in many frames"
            if speed is None:
                assert spans == {morph_ms / 1000}
            else:
                assert len(spans) > 10 and min(spans) < max(spans) <= morph_ms / 1000, sorted(spans)[:5]
            view.render([p for p in path_poses("flyover", *_bounds(s), 2, 3.0)], now=rec.t + morph_ms / 1000)
            for c in range(2):
                assert not view.morphs[c].active
                for m in range(4):
                    np.testing.assert_array_equal(view.renderer.index_buffer(c, m), s.buffer(c, m))
                np.testing.assert_array_equal(view.renderer.camera_positions(c), s.vertex_buffer.positions)
            view.release()


def _bounds(s):
    lo, hi = s.info.mesh.bounds_min, s.info.mesh.bounds_max
    return (lo.x, lo.y, lo.z), (hi.x, hi.y, hi.z)


def test_a_renderer_made_mid_session_starts_from_what_the_client_holds(server, gl, tmp_path):
    with Client(f"127.0.0.1:{server.port}", cache_dir=tmp_path) as client:
        with client.session("terrain", cameras=1, width=160, height=90) as s:
            first = SessionRenderer(s, 64, 64, ctx=gl)
            list(fly(s, first, "circle", 5, draw=False))
            first.release()
            late = SessionRenderer(s, 160, 90, ctx=gl)         # after frames it never saw
            assert not late.mismatches()
            for rec in fly(s, late, "circle", 5, draw=True, verify=True):
                assert not_blank(rec.image, 0.05)
            late.release()


def test_a_cache_mode_session_renderer_mirrors_the_slots_and_the_buffers(server, gl, tmp_path):
    """Cache mode: N vertex slots per camera on the GPU, fed by the frames' vertex writes;
    after every frame (a keyframe among them) the slots the client holds and the index
    buffers read back equal the client library's, and a renderer made mid-session draws
    the same image as the one that saw every frame."""
    with Client(f"127.0.0.1:{server.port}", cache_dir=False) as client:
        with client.session("terrain", cameras=2, width=160, height=90, cache_vertices=1500,
                            cache_strategy="lru_pq") as s:
            view = SessionRenderer(s, 320, 180, ctx=gl)
            assert view.renderer.cache_vertices == 1500
            written = 0
            for rec in fly(s, view, "flyover", 24, fps=10.0, draw=False, verify=True):
                written += sum(cam.vertices_written for f in rec.frames for cam in f.cameras.values())
                if rec.index == 12:
                    s.request_keyframe()
            assert written > 0 and s.protocol.divergences == 0 and s.protocol.bad_frames == 0
            assert all(s.slots(c).n_held <= 1500 for c in range(2))
            late = SessionRenderer(s, 320, 180, ctx=gl)        # replays the held slots and the buffers
            assert not late.mismatches()
            poses = rec.poses
            image = view.render(poses)
            assert not_blank(image, 0.05)
            np.testing.assert_array_equal(late.render(poses), image)
            # A slot that differs on the GPU is found.
            held = int(np.flatnonzero(s.slots(1).held)[0])
            late.renderer.write_vertices(1, [held], s.slots(1).positions[[held]] + 1.0, s.slots(1).normals[[held]],
                                         s.slots(1).uvs[[held]])
            assert late.mismatches() == [(1, -1)]
            view.release()
            late.release()


def test_path_poses_names_the_paths():
    lo, hi = (0, 0, 0), (100, 100, 10)
    assert len(path_poses("line", lo, hi, 3, 1.0)) == 3
    with pytest.raises(ValueError, match="flyover"):
        path_poses("spiral", lo, hi, 1, 0.0)


# -- caveclod render --------------------------------------------------------------------

def test_render_command_writes_frames_an_animation_and_figures(server, tmp_path):
    out = tmp_path / "frames"
    r = run_cli("render", "--target", f"127.0.0.1:{server.port}", "--cameras", "2", "--trajectory", "circle",
                "--frames", "6", "--size", "320x180", "--out", out, "--cache-dir", tmp_path / "cache")
    assert r.returncode == 0, r.stderr
    frames = sorted(out.glob("frame_*.png"))
    assert [f.name for f in frames] == [f"frame_{k:04d}.png" for k in range(6)]
    for f in frames:
        image = png(f)
        assert image.shape == (180, 320, 3)
        assert not_blank(image, 0.05)
    gif = Image.open(out / "animation.gif")
    assert gif.n_frames == 3                     # 30 frames per path second, animated at 15
    report = json.loads((out / "render.json").read_text())
    assert report["frames"] == 6 and report["cameras"] == 2 and report["divergences"] == 0
    assert report["gpu_buffers_verified_frames"] == 6
    assert report["latency_ms"]["p50"] > 0
    assert "latency p50" in r.stdout


def test_render_command_in_cache_mode(server, tmp_path):
    out = tmp_path / "frames"
    r = run_cli("render", "--target", f"127.0.0.1:{server.port}", "--cameras", "2", "--trajectory", "line",
                "--frames", "4", "--size", "320x180", "--out", out, "--cache-vertices", "1200",
                "--cache-strategy", "fa")
    assert r.returncode == 0, r.stderr
    assert all(not_blank(png(f), 0.05) for f in sorted(out.glob("frame_*.png")))
    report = json.loads((out / "render.json").read_text())
    assert (report["cache_vertices"], report["cache_strategy"]) == (1200, "fa")
    assert report["vertices_inserted"] > 0 and report["divergences"] == 0
    assert report["gpu_buffers_verified_frames"] == 4


@pytest.mark.parametrize("args, message", [
    (["--cache-strategy", "lru"], "need --cache-vertices N"),
    (["--cache-vertices", "0"], "at least 1"),
    (["--cache-vertices", "3"], "INVALID_ARGUMENT: Open.cache_vertices is 3"),
    (["--size", "big"], "WIDTHxHEIGHT"),
    (["--cameras", "5"], "1 to 4"),
    (["--frames", "0"], "at least 1"),
    (["--mesh", "moon"], "no mesh 'moon'"),
])
def test_render_command_refuses_bad_options(server, tmp_path, args, message):
    r = run_cli("render", "--target", f"127.0.0.1:{server.port}", "--out", tmp_path, *args, timeout=60)
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr


def test_render_command_says_when_no_server_listens(tmp_path):
    import socket
    with socket.socket() as s:                   # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = run_cli("render", "--target", f"127.0.0.1:{port}", "--out", tmp_path, "--frames", "1", timeout=60)
    assert r.returncode == 2
    assert "caveclod serve" in r.stderr and "Traceback" not in r.stderr


# -- caveclod view ----------------------------------------------------------------------

def test_fly_controller_moves_along_its_heading_and_clamps_pitch():
    fly = FlyController((0, 0, 10), (10, 0, 10), speed=2.0)
    fly.move(1, 0, 0, 1.5)                      # forward along +x
    assert np.allclose(fly.eye, (3, 0, 10))
    fly.move(0, 1, 0, 1.0)                      # right of +x (z up) is -y
    assert np.allclose(fly.eye, (3, -2, 10))
    fly.move(0, 0, -1, 0.5)
    assert np.allclose(fly.eye, (3, -2, 9))
    fly.look(0, 10_000)                         # far down: clamped short of straight down
    eye, target, up = fly.pose()
    d = np.subtract(target, eye)
    assert -1 < d[2] < -0.99 and np.linalg.norm(np.cross(d, up)) > 1e-3
    fly.look(600, 0)                            # 90 degrees to the right: heading -y
    assert fly.forward()[1] < -0.01 and abs(fly.forward()[0]) < 1e-9


def test_view_without_a_display_says_what_to_do(server, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "caveclod.cli", "view", "--target", f"127.0.0.1:{server.port}"],
                       capture_output=True, text=True, timeout=60, env=env, cwd=ROOT)
    assert r.returncode == 2
    assert "no display" in r.stderr and "xvfb-run" in r.stderr and "caveclod render" in r.stderr


@pytest.mark.requires_tool("xvfb-run")
def test_view_draws_a_window_on_a_virtual_screen(server, tmp_path):
    shot = tmp_path / "view.png"
    r = run_cli("view", "--target", f"127.0.0.1:{server.port}", "--cameras", "2", "--size", "320x180",
                "--frames", "40", "--screenshot", shot, "--cache-dir", tmp_path / "cache",
                wrap=("xvfb-run", "-a", "-s", "-screen 0 640x480x24"), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "40 frames drawn, 0 divergences" in r.stdout
    assert not_blank(png(shot), 0.05)


@pytest.mark.requires_tool("xvfb-run")
def test_view_in_cache_mode(server, tmp_path):
    shot = tmp_path / "view.png"
    r = run_cli("view", "--target", f"127.0.0.1:{server.port}", "--size", "320x180", "--frames", "20",
                "--screenshot", shot, "--cache-vertices", "1500", "--cache-strategy", "lru",
                wrap=("xvfb-run", "-a", "-s", "-screen 0 640x480x24"), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "20 frames drawn, 0 divergences" in r.stdout
    assert not_blank(png(shot), 0.05)


# -- caveclod demo ----------------------------------------------------------------------

def test_demo_runs_through_its_own_server_and_stops_it(tmp_path):
    out = tmp_path / "demo"
    r = run_cli("demo", "--out", out, "--frames", "12", "--size", "48", "--image", "480x270", "--keep-every", "4")
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"output in {out}" in r.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 12 and summary["cameras"] == 4
    assert summary["divergences"] == 0 and summary["gpu_buffers_verified_frames"] == 12
    assert summary["operations_per_camera_second"] > 0 and summary["bytes_per_frame"]["median"] > 0
    assert summary["latency_ms"]["p50"] > 0
    assert set(summary["cameras_described"]) == {"A", "B", "C", "D"}
    for name in ("frame.png", "wireframe.png"):
        assert not_blank(png(out / name))
    assert sorted(p.name for p in (out / "frames").glob("*.png")) == \
        ["frame_0000.png", "frame_0004.png", "frame_0008.png", "frame_0011.png"]
    assert Image.open(out / "animation.gif").n_frames == 6
    assert png(out / "contact_sheet.png").shape[1] > 480
    assert (out / "demo.png").stat().st_size > 10_000
    # The server it started is gone.
    with pytest.raises(ProcessLookupError):
        os.kill(summary["server"]["pid"], 0)
    # A second run reuses the mesh it built.
    r = run_cli("demo", "--out", out, "--frames", "3", "--size", "48", "--image", "160x90")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "reusing" in r.stdout


def test_demo_refuses_bad_options(tmp_path):
    r = run_cli("demo", "--out", tmp_path, "--frames", "1", timeout=60)
    assert r.returncode == 2 and "--frames must be at least 2" in r.stderr
