"""The browser viewer in a real headless Chromium (Debian's chromium-headless-shell,
WebGL2 through SwiftShader, driven by Playwright; skipped, saying why, where the
browser is missing).

Each test serves meshes from an in-process server on loopback (gRPC and the
web port both on port 0), opens the page, and reads ``window.caveclodStats``:
frames applied with their CRC checks and no divergence, a picture in every
camera's quadrant, no console error, no request to anywhere but 127.0.0.1,
and the server's message on the page when a session is refused or drained.
"""

from __future__ import annotations

import io
import itertools
import threading
import time
from urllib.parse import urlparse

import numpy as np
import pytest

from service import wait_until

pytestmark = pytest.mark.requires_tool("chromium-headless-shell")

BROWSER_ARGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
WAIT = 60.0
VIEWPORT = {"width": 640, "height": 400}


def launch(p):
    """Chromium through Playwright; a skip, saying why, where the installed browser does not start
    (a machine whose Chromium lacks a library): what the page does is tested once it has started."""
    from playwright.sync_api import Error
    from systemtools import system_tool
    try:
        return p.chromium.launch(executable_path=system_tool("chromium-headless-shell"), args=BROWSER_ARGS)
    except Error as exc:
        pytest.skip(f"chromium-headless-shell is installed but does not start here: {str(exc)[:300]}")


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright
    with sync_playwright() as p:
        chromium = launch(p)
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture(scope="module")
def textured_path(tmp_path_factory):
    """An object with a UV seam, a UV atlas cut into charts and three materials (not a terrain)."""
    from meshes import uv_sphere

    from caveclod.builder.hierarchy import build_static_mesh
    src = uv_sphere(count=(48, 24))
    centre = src.positions[src.face_positions].mean(axis=1)
    src.face_material = np.digitize(centre[:, 2], [-0.3, 0.4]).astype(np.int32)
    src.materials = ["stone", "moss", "snow"]
    path = tmp_path_factory.mktemp("web") / "globe.cvc"
    build_static_mesh(src).save(path)
    return path


class Page:
    """A page of the viewer, with what it logged and asked for."""

    def __init__(self, browser, url: str):
        self.page = browser.new_page(viewport=VIEWPORT)
        self.console_errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: m.type == "error" and self.console_errors.append(m.text))
        self.page.on("pageerror", lambda e: self.console_errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(url)

    def stats(self) -> dict:
        return self.page.evaluate("window.caveclodStats")

    def wait(self, predicate, timeout: float = WAIT) -> dict:
        """Poll the stats (every 0.1 s, for at most ``timeout``) until ``predicate(stats)``; the stats."""
        deadline = time.monotonic() + timeout
        while True:
            stats = self.stats()
            if predicate(stats) or time.monotonic() > deadline:
                return stats
            time.sleep(0.1)

    def error_shown(self) -> str:
        box = self.page.locator("#error")
        return box.inner_text() if box.is_visible() else ""

    def quadrants(self, cameras: int) -> list[np.ndarray]:
        """The screenshot cut into the cameras' rectangles (the HUD's top-left corner left out)."""
        from PIL import Image
        image = np.asarray(Image.open(io.BytesIO(self.page.screenshot())).convert("RGB"))
        h, w = image.shape[:2]
        if cameras == 1:
            parts = [image]
        elif cameras == 2:
            parts = [image[:, : w // 2], image[:, w // 2:]]
        else:
            parts = [image[r * h // 2:(r + 1) * h // 2, c * w // 2:(c + 1) * w // 2] for r in (0, 1) for c in (0, 1)]
        return [p[p.shape[0] // 3:] for p in parts]        # below the HUD

    def close(self) -> None:
        self.page.close()

    def __enter__(self) -> "Page":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _drawn(part: np.ndarray) -> bool:
    """A quadrant shows the mesh: a fifth of it is not sky (blue-grey) and it is shaded (not flat)."""
    rgb = part.astype(np.int32)
    sky = (np.abs(rgb[..., 2] - 205) < 14) & (np.abs(rgb[..., 1] - 168) < 14) & (rgb[..., 0] > 120)
    return (~sky).mean() > 0.2 and float(rgb[~sky].std()) > 3.0


def _only_loopback(requests: list[str]) -> list[str]:
    return [u for u in requests if not u.startswith("data:") and urlparse(u).hostname != "127.0.0.1"]


def _base(server) -> str:
    return f"http://127.0.0.1:{server.web_port}/"


@pytest.mark.parametrize("cameras, morph", [(2, ""), (2, "&morph=8000&morphspeed=5")])
def test_a_terrain_flyover_in_quadrants(make_server, browser, cameras, morph):
    server = make_server(web_port=0)
    with Page(browser, _base(server) + f"?mesh=terrain&cameras={cameras}&trajectory=flyover&tolerance=1{morph}") \
            as page:
        stats = page.wait(lambda s: s["frames"] >= 60 and s["crcChecks"] >= 30 or s["error"])
        assert stats["error"] is None and stats["connected"], stats
        assert stats["frames"] >= 60 and stats["crcChecks"] >= 30 and stats["divergences"] == 0, stats
        assert stats["badFrames"] == 0 and stats["keyframeRequests"] == 0 and stats["facesDrawn"] > 100
        assert stats["cameras"] == cameras and 0 < stats["latencyMsP50"] <= stats["latencyMsP99"]
        # Geomorphs (the page's default) ran: points grew and shrank between frames; their
        # morph targets let the page read linked op streams (its default with them).
        assert stats["morphsStarted"] > 0, stats
        assert stats["frameEncoding"] == "FRAME_ENCODING_OPS_LINKED", stats
        # The vertex buffer came packed (the page's default), under a quarter of its float32 bytes.
        payload = server.sessions.catalogue.get("terrain").vertex_format.payload_bytes
        assert stats["vertexPacked"] and 0 < 4 * stats["vertexDownloadBytes"] < payload, stats
        parts = page.quadrants(cameras)
        assert all(_drawn(p) for p in parts), [float(p.std()) for p in parts]
        # The page holds what the server's mirror holds, buffer for buffer.
        token = next(iter(server.sessions.sessions))
        assert page.page.evaluate("window.caveclodSession.token") == token
        assert not page.console_errors, page.console_errors
        assert not _only_loopback(page.requests), _only_loopback(page.requests)


def test_a_textured_object_circled_with_raw_frames(make_server, browser, textured_path):
    server = make_server(meshes=[textured_path], web_port=0)
    with Page(browser, _base(server) + "?mesh=globe&trajectory=circle&encoding=raw&vertices=float32&strict=1") as page:
        stats = page.wait(lambda s: s["frames"] >= 30 and s["crcChecks"] >= 10 or s["error"])
        assert stats["error"] is None and stats["divergences"] == 0 and stats["crcChecks"] >= 10, stats
        assert not stats["vertexPacked"]
        # &strict=1 asked for the strict error bound: the session's cameras have it.
        assert all(cam.strict_bound for session in server.sessions.sessions.values() for cam in session.cams)
        assert stats["mesh"] == "globe" and stats["facesDrawn"] > 50
        assert all(_drawn(p) for p in page.quadrants(1))
        assert not page.console_errors and not _only_loopback(page.requests)


def test_the_hud_counts_the_parts_a_camera_hides(make_server, browser, tmp_path):
    """A field of small parts circled from its middle: parts behind the camera are hidden
    (issue 18's pruning), and the HUD says how many, from the frames' CameraStats."""
    import caveclod
    path = tmp_path / "debris.cvc"
    caveclod.build("debris", size=4, seed=5).save(path)          # 80 parts
    server = make_server(meshes=[path], web_port=0)
    with Page(browser, _base(server) + "?mesh=debris&trajectory=circle") as page:
        stats = page.wait(lambda s: s["frames"] >= 20 and s["hiddenParts"] > 0 or s["error"])
        assert stats["error"] is None and stats["divergences"] == 0, stats
        assert 0 < stats["hiddenParts"] <= 80, stats
        assert "hidden parts" in page.page.inner_text("#hud")
        assert not page.console_errors and not _only_loopback(page.requests)


def test_the_page_closes_its_session_when_it_unloads(make_server, browser):
    server = make_server(web_port=0, resume_ttl=60)
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate") as page:
        page.wait(lambda s: s["frames"] >= 5)
        assert len(server.sessions.sessions) == 1
        page.page.goto("about:blank")          # pagehide: the page sends Close
        # Closed, not left resumable for the 60 s TTL.
        assert wait_until(lambda: not server.sessions.sessions, timeout=10)


def test_a_bad_mesh_name_is_shown_with_the_servers_message(make_server, browser):
    server = make_server(web_port=0)
    with Page(browser, _base(server) + "?mesh=atlantis&trajectory=circle") as page:
        stats = page.wait(lambda s: s["error"])
        assert "atlantis" in stats["error"] and "not served" in stats["error"]
        assert "atlantis" in page.error_shown()
        assert not _only_loopback(page.requests)


@pytest.mark.parametrize("query, why", [("", "requires a token"), ("&token=wrong", "not accepted"),
                                        ("&token=a%20b", "not accepted")])
def test_a_missing_or_wrong_token_is_shown(make_server, browser, query, why):
    server = make_server(web_port=0, tokens=("good-token",))
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=circle" + query) as page:
        stats = page.wait(lambda s: s["error"])
        assert why in (stats["error"] or "") and why in page.error_shown(), stats
        assert not server.sessions.sessions


@pytest.mark.parametrize("token", ["good-token", "pässwort", "密码"])
def test_a_good_token_opens_the_first_mesh(make_server, browser, token):
    """No ?mesh: the page lists the meshes with its token. Sent as a header, a token beyond ASCII was
    refused by fetch ("non ISO-8859-1 code point") or sent as Latin-1 bytes the server did not match."""
    from urllib.parse import quote
    server = make_server(web_port=0, tokens=(token,))
    with Page(browser, _base(server) + "?trajectory=circle&token=" + quote(token)) as page:
        stats = page.wait(lambda s: s["frames"] >= 5 or s["error"])
        assert stats["error"] is None and stats["frames"] >= 5 and stats["mesh"] == "terrain"


def test_a_drained_server_is_shown_on_the_page(make_server, browser):
    server = make_server(web_port=0)
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=flyover&cameras=4") as page:
        page.wait(lambda s: s["frames"] >= 10)
        drain = threading.Thread(target=server.drain, args=(0.2,))
        drain.start()
        stats = page.wait(lambda s: s["error"])
        drain.join(WAIT)
        assert "shutting down" in stats["error"] and "shutting down" in page.error_shown()
        assert stats["status"]["code"] == 14 and not stats["connected"]
        assert stats["divergences"] == 0


# -- the page's decoder and checksum against Python's, in the browser -------------------

DECODE_IN_PAGE = """async (cases) => {
  const { decodeOps } = await import('/static/opstream.js');
  return cases.map(([ops, old, count, n]) => {
    try {
      const { slots, tris } = decodeOps(Uint8Array.from(ops), Uint32Array.from(old), old.length / 3, count, n);
      return [Array.from(slots), Array.from(tris)];
    } catch (err) {
      return err.constructor.name + ': ' + err.message;
    }
  });
}"""


def _opstream_cases(terrain_path, linked: bool = False) -> tuple[list, object]:
    """([(ops, old rows, count, n_vertices)], Links or None): a flyover's real deltas as op
    streams (``linked``: OPS_LINKED ones, with the mesh's Links), then damaged copies of them."""
    import caveclod
    from caveclod import opstream
    from caveclod.refine.morphtargets import morph_targets

    from flights import flyover_streams
    from fuzzing import damage
    mesh = caveclod.load(terrain_path)
    links = opstream.Links(morph_targets(mesh)) if linked else None
    cases = [(linked_ops if linked else ops, old, d.count, mesh.n_vertices)
             for _, _, d, old, ops, linked_ops in flyover_streams(mesh, links, cameras=1, frames=60, step=0.2)]
    rng = np.random.default_rng(1)
    real = [c for c in cases if c[0]]
    for i in range(600):
        ops, old, count, n = real[i % len(real)]
        cases.append((damage(ops, rng, i), old, count, n))
    return cases, links


def _decoded_alike(cases: list, results: list, decode) -> int:
    """Each page result against Python's ``decode(ops, old, count)``: the same writes, or both
    refusing the stream (the page with an OpStreamError). Returns how many were refused."""
    from caveclod import opstream
    errors = 0
    for (ops, old, count, _), got in zip(cases, results):
        try:
            slots, tris = decode(ops, old, count)
        except opstream.OpStreamError:
            assert isinstance(got, str) and got.startswith("OpStreamError"), "Python refused what the page decoded"
            errors += 1
            continue
        assert not isinstance(got, str), f"the page refused a stream Python decodes: {got}"
        assert got[0] == slots.tolist() and got[1] == tris.ravel().tolist()
    return errors


def test_the_pages_op_stream_decoder_agrees_with_pythons(browser, terrain_path, make_server):
    from caveclod import opstream
    server = make_server(web_port=0)
    cases, _ = _opstream_cases(terrain_path)
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate") as page:
        results = page.page.evaluate(DECODE_IN_PAGE, [(list(ops), old.ravel().tolist(), count, n)
                                                      for ops, old, count, n in cases])
    errors = _decoded_alike(cases, results, lambda ops, old, count: opstream.decode(ops, old, count, cases[0][3]))
    assert errors > 200 and len(cases) - errors > 100      # damaged streams refused, real ones decoded


DECODE_LINKED_IN_PAGE = """async ([targets, cases]) => {
  const { decodeLinked, linksOf } = await import('/static/opstream.js');
  const links = linksOf(Uint32Array.from(targets));
  return cases.map(([ops, old, count]) => {
    try {
      const { slots, tris } = decodeLinked(Uint8Array.from(ops), Uint32Array.from(old), old.length / 3, count, links);
      return [Array.from(slots), Array.from(tris)];
    } catch (err) {
      return err.constructor.name + ': ' + err.message;
    }
  });
}"""


def test_the_pages_linked_op_stream_decoder_agrees_with_pythons(browser, terrain_path, make_server):
    """OPS_LINKED streams of a flyover's real deltas, then damaged copies: the page decodes what
    Python decodes, to the same writes, and refuses what Python refuses."""
    from caveclod import opstream
    server = make_server(web_port=0)
    cases, links = _opstream_cases(terrain_path, linked=True)
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate") as page:
        results = page.page.evaluate(DECODE_LINKED_IN_PAGE, [links.targets.tolist(),
                                                             [(list(ops), old.ravel().tolist(), count)
                                                              for ops, old, count, _ in cases]])
    errors = _decoded_alike(cases, results, lambda ops, old, count: opstream.decode_linked(ops, old, count, links))
    assert errors > 200 and len(cases) - errors > 100


def test_the_pages_crc32_is_zlibs(browser, make_server):
    import zlib
    server = make_server(web_port=0)
    rng = np.random.default_rng(2)
    blobs = [b"", b"a", bytes(range(256))] + [rng.bytes(int(rng.integers(1, 5000))) for _ in range(20)]
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate") as page:
        got = page.page.evaluate("async (blobs) => { const { crc32 } = await import('/static/crc32.js');"
                                 " return blobs.map((b) => crc32(Uint8Array.from(b))); }", [list(b) for b in blobs])
    assert got == [zlib.crc32(b) for b in blobs]


UNPACK_IN_PAGE = """async (cases) => {
  const { unpackVertices } = await import('/static/vertexpack.js');
  const { crc32 } = await import('/static/crc32.js');
  const out = [];
  for (const [packing, format, packed] of cases) {
    try {
      out.push(crc32(await unpackVertices(packing, format, Uint8Array.from(packed))));
    } catch (err) {
      out.push(err.constructor.name + ': ' + err.message);
    }
  }
  return out;
}"""


def test_the_pages_vertex_unpacker_makes_pythons_bytes(browser, make_server, textured_path, monkeypatch):
    """The page decodes packed buffers (terrain, a coloured random buffer, bits 8-24, with and without
    morph targets, deflated whole and in two halves) to the very bytes caveclod.vertexpack makes, and
    refuses damaged ones."""
    import caveclod
    from caveclod import vertexpack, wire
    server = make_server(web_port=0)
    rng = np.random.default_rng(3)
    mesh = caveclod.load(textured_path)
    buffers = [(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors)]
    d = 500
    n = rng.normal(size=(d, 3))
    buffers.append(((5e5 + rng.random((d, 3)) * 3e3).astype(np.float32),
                    (n / np.linalg.norm(n, axis=1)[:, None]).astype(np.float32),
                    (rng.random((d, 2)) * 700 - 30).astype(np.float32), rng.integers(0, 256, (d, 4), dtype=np.uint8)))
    cases, want = [], []
    whole = vertexpack.PARALLEL_DEFLATE_BYTES
    for (p, nrm, uv, col), (bits, morph, halves) in itertools.product(
            buffers, ((8, False, False), (20, True, False), (24, False, False), (16, True, True))):
        # halves: deflated in two halves at once, as buffers past PARALLEL_DEFLATE_BYTES are
        monkeypatch.setattr(vertexpack, "PARALLEL_DEFLATE_BYTES", 0 if halves else whole)
        targets = np.maximum(np.arange(len(p)) - rng.integers(0, 40, len(p)), 0) if morph else None
        packed = vertexpack.pack(p, nrm, uv, col, bits, targets)
        blocks = wire.vertex_blocks(p, nrm, uv, np.zeros((0, 4), np.uint8) if col is None else col)
        fmt = vertexpack.vertex_format(blocks, morph)
        msg = vertexpack.to_message(packed, "ab" * 16)       # as protobufjs names its fields
        o = msg.position_origin
        packing = {"positionOrigin": {"x": o.x, "y": o.y, "z": o.z}, "positionStep": msg.position_step,
                   "normalBits": msg.normal_bits, "texcoordStep": msg.texcoord_step}
        fmt_dict = {"vertexCount": int(fmt.vertex_count),
                    "attributes": [{"semantic": a.semantic} for a in fmt.attributes]}
        cases.append((packing, fmt_dict, list(packed.data)))
        want.append(packed.decoded_crc32)
        bad = bytearray(packed.data)
        bad[len(bad) // 3] ^= 0x04
        cases.append((packing, fmt_dict, list(bad)))
        want.append(None)
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate") as page:
        got = page.page.evaluate(UNPACK_IN_PAGE, cases)
    for g, w in zip(got, want):
        if w is None:
            assert isinstance(g, str) and g.startswith("PackedVertexError"), g
        else:
            assert g == w, g


def _in_pieces(surfaces: list) -> list:
    """``[(material, count, slots, flat tris)]`` with each surface of more than one row cut in two row
    ranges, each with the buffer's count, as caveclod.frames.frame_parts cuts a frame across parts."""
    out = []
    for m, count, slots, tris in surfaces:
        h = len(slots) // 2
        out += [(m, count, slots[:h], tris[:3 * h]), (m, count, slots[h:], tris[3 * h:])] if h else \
            [(m, count, slots, tris)]
    return out


GEOMORPH_IN_PAGE = """async ([positions, targets, materials, duration, speed, steps]) => {
  const { Geomorphs, pointsOf } = await import('/static/geomorph.js');
  const pos = Float32Array.from(positions), tg = Uint32Array.from(targets);
  const g = new Geomorphs(pos, tg, materials, duration, pointsOf(pos, tg), speed);
  const out = [];
  for (const [kind, now, surfaces, eye, kappa] of steps) {
    if (eye !== null) g.lookFrom(eye, kappa);
    if (kind === 'frame') {
      g.apply(surfaces.map(([m, count, slots, tris]) => ({ material: m, count, slots: Uint32Array.from(slots), tris: Uint32Array.from(tris) })), false, now);
    } else if (kind === 'key' || kind === 'basekey') {
      g.apply(surfaces.map(([m, count, slots, tris]) => ({ material: m, count, slots: Uint32Array.from(slots), tris: Uint32Array.from(tris) })), true, now, kind === 'key');
    } else {
      g.tick(now);
    }
    const mv = g.moving(now);
    out.push([Array.from({ length: materials }, (_, m) => Array.from(g.display(m))), Array.from(mv.vertices), Array.from(mv.positions), g.active.size, g.snaps]);
  }
  return out;
}"""


@pytest.mark.parametrize("speed, cut", [(None, False), (20.0, False), (None, True)])
def test_the_pages_geomorphs_agree_with_pythons(browser, make_server, terrain_path, speed, cut):
    """The page's geomorph.js, fed the frames of a flight with splits, collapses and a keyframe (its
    first frame, after a keyframe of no pose, shown as it is), draws
    the display buffers and moving positions that caveclod.client.geomorph draws, step for step; with
    a speed too, each morph timed by its path on screen from the frame's camera; and fed every
    material's writes in pieces (a frame cut across parts), what Python draws fed them whole."""
    import caveclod
    from caveclod.client.geomorph import Geomorphs, pixels_per_unit
    from caveclod.paths import flyover
    from caveclod.refine.morphtargets import morph_targets
    from caveclod.wire import Surface
    server = make_server(web_port=0)
    mesh = caveclod.load(terrain_path)
    lo, hi = mesh.bounds()
    targets = morph_targets(mesh)
    cam = mesh.new_camera()
    morphs = Geomorphs(mesh.vertex_positions, targets, cam.n_materials, 0.3, speed=speed)

    def key():
        return [(m, int(cam.cnt[m]), list(range(int(cam.cnt[m]))), cam.index_buffer(m).ravel().tolist())
                for m in range(cam.n_materials)]
    steps, want, spans = [], [], set()

    def step(kind, now, surfaces, view=None):
        eye = None if view is None else [float(x) for x in view.eye]
        kappa = None if view is None else pixels_per_unit(view.height, view.fov_y)
        steps.append((kind, now, _in_pieces(surfaces) if cut else surfaces, eye, kappa))
        if view is not None:
            morphs.look_from(eye, kappa)
        objs = [Surface(m, c, np.asarray(sl, np.int64), np.asarray(t, np.int64).reshape(-1, 3))
                for m, c, sl, t in surfaces]
        if kind == "tick":
            morphs.tick(now)
        else:
            morphs.apply(objs, kind in ("key", "basekey"), now, posed=kind != "basekey")
        v, p = morphs.moving(now)
        spans.update(m.span for m in morphs.active.values())
        want.append(([morphs.display(m).ravel().tolist() for m in range(cam.n_materials)],
                     dict(zip(v.tolist(), map(tuple, p.tolist()))), len(morphs.active), morphs.snaps))
    step("basekey", 0.0, key())                     # a session's first keyframe: the base mesh, no pose yet
    for f in range(1, 70):
        now = f / 30
        view = caveclod.View.from_pose(flyover(lo, hi, 0, f / 1.5), width=640, height=360, tolerance_px=1.0)
        delta = cam.update(view)
        if f == 40:                                     # a keyframe in the middle: the camera starts over
            step("key", now, key())
            continue
        step("frame", now, [(m, int(d.count), d.slots.tolist(), np.asarray(d.tris).ravel().tolist())
                            for m, d in delta.surfaces.items()], view)
        if f % 3 == 0:
            step("tick", now + 0.01, [])
    with Page(browser, _base(server) + "?mesh=terrain&trajectory=rotate&morph=0") as page:
        got = page.page.evaluate(GEOMORPH_IN_PAGE, [mesh.vertex_positions.ravel().tolist(), targets.tolist(),
                                                    cam.n_materials, 0.3, speed, steps])
    busy = 0
    for i, ((display, verts, where, active, snaps), (w_display, w_moving, w_active, w_snaps)) in \
            enumerate(zip(got, want)):
        assert display == w_display, f"step {i}: display buffers differ"
        moving = dict(zip(verts, map(tuple, np.asarray(where, np.float32).reshape(-1, 3).tolist())))
        assert moving == w_moving, f"step {i}: moving positions differ"
        assert (active, snaps) == (w_active, w_snaps), i
        busy += active > 0
    assert busy > 20, "the flight must morph"
    if speed is not None:                           # morphs of many lengths, some cut at the duration
        assert len(spans) > 10 and min(spans) < 0.3 and max(spans) == 0.3, sorted(spans)[:5]
