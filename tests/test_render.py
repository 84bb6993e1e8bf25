"""The GPU renderer on small scenes made here: buffers, validation, textures,
lighting, wireframe, quadrants, clip planes, images out; and the built-ins
are not blank. Everything runs offscreen (EGL, llvmpipe) from one context per
module (the ``gl`` fixture)."""

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import caveclod
from caveclod import paths
from caveclod.render import (Camera, Renderer, RenderError, Vertices, contact_sheet, create_context, quadrants,
                             save_animation, save_png)
from caveclod.render import context as render_context
from caveclod.render.buffers import TRIANGLE_BYTES
from caveclod.render.renderer import BACKGROUND

SKY = np.round(np.array(BACKGROUND) * 255).astype(np.uint8)
DOWN = dict(target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))      # looking down -z, +y up the image


def grid(n: int, size: float = 2.0, uv_scale: float = 1.0, z: float = 0.0):
    """An n x n-cell square in the plane ``z`` facing +z, centred on the origin.

    Returns (Vertices, (2 n^2, 3) uint32 triangles, counter-clockwise from above).
    """
    t = np.linspace(-size / 2, size / 2, n + 1)
    x, y = np.meshgrid(t, t)
    pos = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)].astype(np.float32)
    nrm = np.tile(np.float32([0, 0, 1]), (len(pos), 1))
    uv = ((pos[:, :2] / size + 0.5) * uv_scale).astype(np.float32)
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return Vertices(pos, nrm, uv), tris.astype(np.uint32)


def sphere(rings: int = 24, segments: int = 48):
    """A unit UV sphere: (Vertices, (k, 3) uint32 outward-wound triangles)."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, segments + 1), indexing="ij")
    pos = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    uv = np.stack([phi / (2 * np.pi), theta / np.pi], -1).reshape(-1, 2)
    ids = np.arange(pos.shape[0]).reshape(rings + 1, segments + 1)
    a, b, c, d = ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]
    tris = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    p = pos.astype(np.float32)
    return Vertices(p, p.copy(), uv.astype(np.float32)), tris.astype(np.uint32)


def luminance(image: np.ndarray) -> np.ndarray:
    return image.astype(np.float64) @ [0.299, 0.587, 0.114]


def is_sky(image: np.ndarray) -> np.ndarray:
    return (np.abs(image.astype(int) - SKY) <= 1).all(axis=-1)


# -- context ------------------------------------------------------------------

def test_the_renderer_imports_only_numpy_moderngl_and_pillow():
    code = ("import sys, caveclod.render; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'trimesh', 'grpc', 'server') "
            "or m.startswith(('caveclod.refine', 'caveclod.builder', 'caveclod.kernels', 'caveclod.staticmesh'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_missing_opengl_names_what_to_install(monkeypatch):
    def no_gl(**kwargs):
        raise Exception("libEGL.so: cannot open shared object file")
    monkeypatch.setattr(render_context.moderngl, "create_context", no_gl)
    with pytest.raises(RenderError, match="libegl1 libgl1-mesa-dri") as info:
        create_context()
    assert "libEGL.so" in str(info.value)


# -- index buffers: patching, growth, read-back, validation ---------------------

def test_slot_runs_are_single_writes_and_gpu_holds_the_triangles(gl):
    verts, tris = grid(4)
    with Renderer(32, 32, verts, ["grass"], ctx=gl) as r:
        assert r.stats.vertex_bytes == len(verts.positions) * 32 and r.stats.index_bytes == 0
        r.apply(0, 0, 10, tris[:10])                                # keyframe-like: consecutive from 0
        assert (r.stats.index_writes, r.stats.index_bytes) == (1, 10 * TRIANGLE_BYTES)
        model = tris[:10].copy()
        slots = np.array([0, 1, 2, 5, 6, 9])                        # three runs: 0-2, 5-6, 9
        new = tris[20:26]
        r.apply(0, 0, 10, new, slots=slots)
        model[slots] = new
        assert (r.stats.index_writes, r.stats.index_bytes) == (4, 16 * TRIANGLE_BYTES)
        np.testing.assert_array_equal(r.index_buffer(0, 0), model)
        r.apply(0, 0, 12, tris[30:32], first_slot=10)               # appends
        r.apply(0, 0, 7, tris[:0])                                  # truncation writes nothing
        model = np.r_[model, tris[30:32]][:7]
        np.testing.assert_array_equal(r.index_buffer(0, 0), model)
        assert r.stats.index_writes == 5 and r.counts(0) == [7]
        assert r.stats.vertex_bytes == len(verts.positions) * 32      # never uploaded again


def test_growth_is_geometric_and_copies_on_the_gpu(gl):
    verts, tris = grid(40)                                          # 3200 triangles
    with Renderer(32, 32, verts, ["grass"], ctx=gl) as r:
        for count in range(1, len(tris) + 1, 7):                   # append 7 at a time
            first = r.counts(0)[0]
            r.apply(0, 0, count, tris[first:count], first_slot=first)
        np.testing.assert_array_equal(r.index_buffer(0, 0), tris[:r.counts(0)[0]])
        # 256 -> 384 -> 576 -> 864 -> 1296 -> 1944 -> 2916 -> 4374: 7 growths, not hundreds.
        assert r.stats.grows == 7
        assert r.stats.index_bytes == r.counts(0)[0] * TRIANGLE_BYTES   # the copies were not uploads
        assert r.stats.gpu_copy_bytes > 0


def test_reset_empties_one_camera(gl):
    verts, tris = grid(4)
    with Renderer(32, 32, verts, ["grass", "rock"], cameras=2, ctx=gl) as r:
        for camera in range(2):
            for material in range(2):
                r.apply(camera, material, 5, tris[material * 5: material * 5 + 5])
        r.reset(0)
        assert r.counts(0) == [0, 0] and r.counts(1) == [5, 5]
        assert r.index_buffer(0, 1).shape == (0, 3)
        np.testing.assert_array_equal(r.index_buffer(1, 1), tris[5:10])


BAD_WRITES = {   # case: (the writes, what the message must say)
    "slot at count": (dict(count=8, tris=[[0, 1, 2]], slots=[8]), "slot 8 is outside .* count 8"),
    "negative slot": (dict(count=8, tris=[[0, 1, 2]], slots=[-1]), "slot -1 is outside"),
    "vertex index past d": (dict(count=8, tris=[[0, 1, 25]], slots=[3]), "vertex index 25 .* 25 vertices"),
    "negative vertex index": (dict(count=8, tris=np.array([[0, -1, 2]]), slots=[3]), "vertex index -1"),
    "tris of 4 corners": (dict(count=8, tris=np.zeros((2, 4), np.uint32), slots=[1, 2]), r"shape \(k, 3\)"),
    "float tris": (dict(count=8, tris=np.zeros((1, 3), np.float32), slots=[1]), "integer vertex indices"),
    "slots not one per triangle": (dict(count=8, tris=[[0, 1, 2], [1, 2, 3]], slots=[1]), "one per triangle"),
    "slots descending": (dict(count=8, tris=[[0, 1, 2], [1, 2, 3]], slots=[4, 3]), "ascending"),
    "slots repeated": (dict(count=8, tris=[[0, 1, 2], [1, 2, 3]], slots=[3, 3]), "ascending"),
    "consecutive run past count": (dict(count=8, tris=np.zeros((3, 3), np.uint32), first_slot=6),
                                   "from slot 6 run past count 8"),
    "negative count": (dict(count=-1, tris=np.zeros((0, 3), np.uint32)), "count must be a whole number"),
    "fractional count": (dict(count=2.5, tris=np.zeros((0, 3), np.uint32)), "count must be a whole number"),
    "unknown camera": (dict(camera=2, count=8, tris=[[0, 1, 2]], slots=[1]), "camera must be 0 .. 1"),
    "unknown material": (dict(material=1, count=8, tris=[[0, 1, 2]], slots=[1]), "material must be 0 .. 0"),
}


@pytest.mark.parametrize("case", BAD_WRITES)
def test_bad_writes_raise_and_leave_the_buffer_unchanged(gl, case):
    verts, tris = grid(4)                                           # 25 vertices
    with Renderer(32, 32, verts, ["grass"], cameras=2, ctx=gl) as r:
        r.apply(0, 0, 6, tris[:6])
        before, stats = r.index_buffer(0, 0), (r.stats.index_bytes, r.stats.index_writes, r.stats.grows)
        writes, message = BAD_WRITES[case]
        args = dict(camera=0, material=0, slots=None, first_slot=0) | writes
        with pytest.raises(ValueError, match=message):
            r.apply(args["camera"], args["material"], args["count"], args["tris"], slots=args["slots"],
                    first_slot=args["first_slot"])
        np.testing.assert_array_equal(r.index_buffer(0, 0), before)
        assert r.counts(0) == [6]
        assert (r.stats.index_bytes, r.stats.index_writes, r.stats.grows) == stats


def test_bad_vertex_buffers_and_options_are_refused(gl):
    verts, _ = grid(2)
    with pytest.raises(ValueError, match="normals"):
        Renderer(32, 32, Vertices(verts.positions, verts.normals[:-1], verts.uvs), ["a"], ctx=gl)
    with pytest.raises(ValueError, match="NaN"):
        Renderer(32, 32, Vertices(verts.positions * np.nan, verts.normals, verts.uvs), ["a"], ctx=gl)
    with pytest.raises(ValueError, match="colors"):
        Renderer(32, 32, Vertices(*verts[:3], np.zeros((9, 4), np.float32)), ["a"], ctx=gl)
    with pytest.raises(ValueError, match="lo <= hi"):
        Renderer(32, 32, verts, ["a"], bounds=((0, 0, 1), (1, 1, 0)), ctx=gl)
    with pytest.raises(ValueError, match="cameras"):
        Renderer(32, 32, verts, ["a"], cameras=5, ctx=gl)
    with pytest.raises(ValueError, match="unknown material"):
        Renderer(32, 32, verts, ["a"], textures={3: np.zeros((4, 4, 3), np.uint8)}, ctx=gl)
    with pytest.raises(ValueError, match="texture"):
        Renderer(32, 32, verts, ["a"], textures={0: np.zeros((4, 4), np.uint8)}, ctx=gl)
    with Renderer(32, 32, verts, ["a"], ctx=gl) as r:
        with pytest.raises(ValueError, match="one view per camera"):
            r.render([])
        with pytest.raises(ValueError, match="parallel"):
            r.render([Camera((0, 0, 1), (0, 0, 0), up=(0, 0, 1))])


# -- textures, lighting, wireframe ------------------------------------------------

def top_down(material_name=None, textures=None, uv_scale=4.0, size=64, colors=None, gl=None):
    """The image of a lit square filling the view, seen straight from above,
    lit straight from above (so a pixel is its texel, filtered)."""
    verts, tris = grid(8, uv_scale=uv_scale)
    if colors is not None:
        verts = Vertices(*verts[:3], colors)
    with Renderer(size, size, verts, [material_name], textures=textures, light=(0, 0, 1), ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        # fov 60 from height 1.2 sees -0.69..0.69 of the square's -1..1.
        return r.render([Camera(eye=(0, 0, 1.2), fov_y=60.0, **DOWN)])


def test_palette_texture_per_terrain_class(gl):
    mean = {name: top_down(name, gl=gl).reshape(-1, 3).mean(axis=0) for name in
            ("water", "grass", "rock", "snow", "stone", "moss")}
    r, g, b = mean["water"]
    assert b > g > r and b > 100
    r, g, b = mean["grass"]
    assert g > r + 30 and g > b + 40
    assert np.ptp(mean["rock"]) < 25 and 70 < mean["rock"].mean() < 150      # grey, mid
    assert mean["snow"].min() > 200                                            # white
    for name in ("stone", "moss"):                                             # unknown: neutral, light
        assert np.ptp(mean[name]) < 50 and mean[name].mean() > 120
    assert np.abs(mean["stone"] - mean["moss"]).max() > 5                      # yet told apart
    for name in ("water", "grass", "rock", "snow", "stone"):
        # Procedural detail: the tiling shows (a flat colour would have no spread).
        assert luminance(top_down(name, gl=gl)).std() > 2.0, name


def test_explicit_texture_is_used_with_v_up_from_row_0(gl):
    image = np.zeros((8, 8, 3), np.uint8)
    image[:4, :4] = (255, 0, 0)          # row 0 is v = 0: the square's -y side, the bottom of the image
    image[:4, 4:] = (0, 255, 0)
    image[4:, :4] = (0, 0, 255)
    image[4:, 4:] = (255, 255, 255)
    got = top_down("water", textures={0: image}, uv_scale=1.0, gl=gl)
    corners = {"bottom left": got[56, 8], "bottom right": got[56, 56], "top left": got[8, 8], "top right": got[8, 56]}
    expect = {"bottom left": (255, 0, 0), "bottom right": (0, 255, 0), "top left": (0, 0, 255),
              "top right": (255, 255, 255)}
    for where, colour in expect.items():
        assert np.abs(corners[where].astype(int) - colour).max() <= 2, (where, corners[where])


def test_vertex_colours_tint_the_texture(gl):
    verts, _ = grid(8)
    red = np.tile(np.uint8([255, 0, 0, 255]), (len(verts.positions), 1))
    tinted = top_down("snow", colors=red, gl=gl).reshape(-1, 3).mean(axis=0)
    assert tinted[0] > 200 and tinted[1] < 5 and tinted[2] < 5


def test_lighting_shades_a_sphere_from_the_lit_side(gl):
    verts, tris = sphere()
    with Renderer(96, 96, verts, ["snow"], light=(1, 0, 0), ambient=0.2, ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        image = r.render([Camera(eye=(0, -4, 0), target=(0, 0, 0), up=(0, 0, 1), fov_y=40)])
    lum, body = luminance(image), ~is_sky(image)
    left, right = body.copy(), body.copy()
    left[:, 48:] = False                 # +x (towards the light) is the right of the image
    right[:, :48] = False
    assert lum[right].mean() > 2.0 * lum[left].mean()
    assert lum[body].std() > 40          # not flat
    assert lum[left].min() > 0.15 * 255  # the ambient term lights the far side


def test_back_faces_are_lit_from_their_side(gl):
    verts, tris = grid(4)                                        # front faces look up (+z)
    with Renderer(32, 32, verts, ["snow"], light=(0, 0, -1), ambient=0.1, ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        above = luminance(r.render([Camera(eye=(0, 0, 1.2), **DOWN)]))
        below = luminance(r.render([Camera(eye=(0, 0, -1.2), **DOWN)]))  # sees the back faces
    # Lit from below: the back faces (normals flipped towards the eye) get
    # the light, the front faces only the ambient tenth.
    assert below.mean() > 200 and above.mean() < 0.15 * below.mean()


def test_wireframe_darkens_the_edges_and_nothing_else(gl):
    verts, tris = grid(1, size=2.0)                 # one square, two triangles, diagonal from (-1,-1) to (1,1)
    with Renderer(65, 65, verts, ["snow"], light=(0, 0, 1), ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        view = [Camera(eye=(0, 0, 3.0), fov_y=60.0, **DOWN)]
        plain, wire = r.render(view), r.render(view, wireframe=True)
    # The square covers the image's middle; its diagonal runs bottom-left to top-right.
    inside = ~is_sky(plain)
    rows, cols = np.nonzero(inside)
    r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
    dark = luminance(wire) < 60
    assert not (luminance(plain) < 60).any()
    on_diagonal = [dark[i, round(c1 - (i - r0) * (c1 - c0) / (r1 - r0)) - 1:][:3].any() for i in range(r0 + 3, r1 - 2)]
    assert len(on_diagonal) > 25 and all(on_diagonal)
    assert dark[r0 + 3:r1 - 2, c0:c0 + 2].any(axis=1).all() and dark[r0:r0 + 2, c0 + 3:c1 - 2].any(axis=0).all()
    ii, jj = np.mgrid[0:65, 0:65]
    near_edge = ((np.abs(ii - r0) <= 2) | (np.abs(ii - r1) <= 2) | (np.abs(jj - c0) <= 2) | (np.abs(jj - c1) <= 2)
                 | (np.abs((ii - r0) * (c1 - c0) + (jj - c1) * (r1 - r0)) <= 3 * (r1 - r0)))
    away = inside & ~near_edge
    assert away.sum() > 500
    assert np.abs(wire[away].astype(int) - plain[away]).max() <= 1


# -- quadrants --------------------------------------------------------------------

def test_quadrant_layout_tiles_the_image():
    assert quadrants(101, 51, 1) == [(0, 0, 101, 51)]
    assert quadrants(101, 51, 2) == [(0, 0, 50, 51), (50, 0, 51, 51)]
    for n in (3, 4):
        cover = np.zeros((51, 101), int)
        for x, y, w, h in quadrants(101, 51, n):
            cover[y:y + h, x:x + w] += 1
        assert cover.max() == 1 and cover.sum() == (101 * 51 if n == 4 else 101 * 51 - 51 * 26)


def test_draw_into_a_window_framebuffer_and_resize(gl):
    verts, tris = sphere()
    view = [Camera(eye=(0, -4, 1), target=(0, 0, 0))]
    with Renderer(64, 48, verts, ["rock"], ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        image = r.render(view)
        window = gl.simple_framebuffer((64, 48))          # what a window's ctx.screen would be
        r.draw(view, target=window)
        drawn = np.frombuffer(window.read(components=3, alignment=1), np.uint8).reshape(48, 64, 3)[::-1]
        window.release()
        np.testing.assert_array_equal(drawn, image)
        vertex_bytes = r.stats.vertex_bytes
        r.resize(96, 40)
        resized = r.render(view)
        assert r.stats.vertex_bytes == vertex_bytes and r.counts(0) == [len(tris)]
    with Renderer(96, 40, verts, ["rock"], ctx=gl) as fresh:
        fresh.apply(0, 0, len(tris), tris)
        np.testing.assert_array_equal(resized, fresh.render(view))


@pytest.fixture(scope="module")
def terrain():
    return caveclod.build("default", size=64)


def refined(mesh, poses, width, height, tolerance_px=1.0):
    """{camera: {material: (k, 3) uint32}} for each pose, refined by the core."""
    buffers = {}
    for k, pose in enumerate(poses):
        cam = mesh.new_camera()
        cam.update(caveclod.View(eye=pose.eye, target=pose.target, up=pose.up, width=width, height=height,
                                 tolerance_px=tolerance_px))
        buffers[k] = cam.triangles()
    return buffers


def mesh_vertices(mesh):
    return Vertices(mesh.vertex_positions, mesh.vertex_normals, mesh.vertex_uvs, mesh.vertex_colors)


def draw(gl, mesh, poses, width, height, buffers, wireframe=False):
    with Renderer(width, height, mesh_vertices(mesh), mesh.materials, cameras=len(poses), ctx=gl) as r:
        for camera, tris in buffers.items():
            for material, t in tris.items():
                r.apply(camera, material, len(t), t)
        return r.render(poses, wireframe=wireframe)


def test_four_cameras_draw_four_different_quadrants_each_its_own_view(gl, terrain):
    lo, hi = terrain.bounds()
    poses = [paths.flyover(lo, hi, k, 4.0) for k in range(4)]
    buffers = refined(terrain, poses, 96, 72)
    image = draw(gl, terrain, poses, 192, 144, buffers)
    quads = [image[y:y + h, x:x + w] for x, y, w, h in quadrants(192, 144, 4)]
    for a in range(4):
        for b in range(a + 1, 4):
            assert np.abs(quads[a].astype(int) - quads[b]).mean() > 10, (a, b)
    # Each quadrant is that camera drawn alone at the quadrant's size, but for
    # rounding: window coordinates offset by the quadrant's corner keep fewer
    # fraction bits, so an interpolated colour may move by a level.
    for k in range(4):
        alone = draw(gl, terrain, [poses[k]], 96, 72, {0: buffers[k]})
        diff = np.abs(quads[k].astype(int) - alone).max(axis=-1)
        assert diff.max() <= 2 and (diff > 0).mean() < 0.002, k


def test_one_camera_fills_the_image_and_a_missing_fourth_is_background(gl, terrain):
    lo, hi = terrain.bounds()
    centre = 0.5 * (lo + hi)
    down = Camera(eye=(centre[0], centre[1], hi[2] + 2500.0), target=(centre[0], centre[1], lo[2]),
                  up=(0, 1, 0), fov_y=60.0)
    buffers = refined(terrain, [down], 80, 60)
    one = draw(gl, terrain, [down], 80, 60, buffers)
    assert not is_sky(one).any()                                  # all of the image, no quadrant
    three = draw(gl, terrain, [down] * 3, 80, 60, {k: buffers[0] for k in range(3)})
    assert is_sky(three[30:, 40:]).all() and not is_sky(three[:30, :40]).any()


# -- clip planes --------------------------------------------------------------------

@pytest.mark.parametrize("scale", [1.0, 1e-4])        # a 10 km terrain, and the same scene 1 m wide
def test_no_z_fighting_with_the_eye_inside_a_deep_scene_box(gl, scale):
    """Two parallel squares 10 m apart across 10 km, seen from 1 km above the
    lower one, in a scene box reaching 3 km up: the eye is inside the box, so
    the near plane is the floor far / 8192 and a depth step at the far end
    is far / 2048, about 5 m. The lower square (snow, drawn first, so it
    wins depth ties) must not show through the upper one (water) anywhere."""
    low, tris = grid(2, size=10000.0 * scale, z=0.0)
    high, _ = grid(2, size=10000.0 * scale, z=10.0 * scale)
    verts = Vertices(*(np.r_[a, b] for a, b in zip(low[:3], high[:3])))
    bounds = (np.array([-5000, -5000, 0]) * scale, np.array([5000, 5000, 3000]) * scale)
    with Renderer(160, 120, verts, ["snow", "water"], bounds=bounds, ctx=gl) as r:
        r.apply(0, 0, len(tris), tris)
        r.apply(0, 1, len(tris), tris + len(low.positions))
        view = Camera(eye=np.array([0, -4000, 1000]) * scale, target=np.array([0, 3000, 0]) * scale)
        assert view.clip_planes(*bounds, 4 / 3)[0] == pytest.approx(view.clip_planes(*bounds, 4 / 3)[1] / 8192)
        image = r.render([view])
    ground = ~is_sky(image)
    assert ground.mean() > 0.5
    assert not (luminance(image[ground]) > 180).any()


def test_clip_planes_hold_the_scene():
    lo, hi = np.array([0.0, 0.0, 300.0]), np.array([10000.0, 10000.0, 1536.0])
    above = Camera(eye=(2500, 2500, 2536), target=(3500, 2500, 900))
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    def depths(camera):          # of the box's corners along the view
        forward = np.subtract(camera.target, camera.eye)
        return (corners - camera.eye) @ (forward / np.linalg.norm(forward))

    near, far = above.clip_planes(lo, hi, 16 / 9)
    assert 500 < near and depths(above).max() < far < 1.02 * depths(above).max()
    inside = Camera(eye=(5000, 5000, 800), target=(6000, 5000, 700))
    near, far = inside.clip_planes(lo, hi, 16 / 9)
    assert near == pytest.approx(far / 8192) and depths(inside).max() < far
    obj = Camera(eye=(3.0, 0, 0), target=(0, 0, 0), fov_y=90.0)
    near, far = obj.clip_planes(-np.ones(3), np.ones(3), 1.0)
    # The box's nearest point is 2 away; in the frustum's corner (cos = 1/sqrt(3)) it is 2/sqrt(3) deep.
    assert near == pytest.approx(0.99 * 2 / np.sqrt(3)) and far == pytest.approx(4 / 0.99)


# -- built-ins, images out -------------------------------------------------------------

@pytest.mark.parametrize("name,size", [("default", 64), ("rough", 64), ("scan", 48)])
def test_builtin_meshes_render_not_blank(gl, name, size, terrain):
    mesh = terrain if name == "default" else caveclod.build(name, size=size)
    lo, hi = mesh.bounds()
    if name == "scan":      # the scanned side faces +y: look at it from there, half-way in
        poses = [paths.line(lo, hi, 3, 16.0), paths.circle(lo, hi, 1, 2.0)]
    else:
        poses = [paths.flyover(lo, hi, k, 2.0) for k in range(2)]
    image = draw(gl, mesh, poses, 160, 60, refined(mesh, poses, 80, 60))
    for x, y, w, h in quadrants(160, 60, 2):
        quadrant = image[y:y + h, x:x + w]
        assert is_sky(quadrant).mean() < 0.9                         # the mesh is in view
        assert luminance(quadrant)[~is_sky(quadrant)].std() > 3.0    # shaded and textured, not flat
    assert luminance(image).std() > 10.0


def test_png_animation_and_contact_sheet(tmp_path):
    frames = [np.full((40, 64, 3), 40 * k, np.uint8) for k in range(5)]
    png = save_png(tmp_path / "frame.png", frames[2])
    np.testing.assert_array_equal(np.asarray(Image.open(png)), frames[2])
    for suffix in ("apng", "gif"):
        path = save_animation(tmp_path / f"walk.{suffix}", frames, fps=10)
        with Image.open(path) as anim:
            assert anim.n_frames == 5 and anim.is_animated and anim.info["duration"] == 100
            anim.seek(3)
            assert np.abs(np.asarray(anim.convert("RGB")).astype(int) - 120).max() <= 2
    sheet = contact_sheet(frames, columns=3, gap=2, labels=[f"{k}" for k in range(5)])
    assert sheet.shape == (2 * 42 + 2, 3 * 66 + 2, 3)
    frame4 = sheet[2 + 42: 2 + 42 + 40, 2 + 66: 2 + 66 + 64]           # row 1, column 1
    np.testing.assert_array_equal(frame4[20:, 30:], frames[4][20:, 30:])
    assert (frame4[:20, :30] != frames[4][:20, :30]).any()             # its label
    with pytest.raises(ValueError, match="same size"):
        contact_sheet([frames[0], frames[1][:5]])
    with pytest.raises(ValueError, match="animation"):
        save_animation(tmp_path / "walk.mp4", frames)


def test_renderers_with_contexts_of_their_own_each_draw_in_their_own(gl):
    """Each renderer made without ``ctx=`` has an EGL context, and GL calls go to the current one:
    the last made. A second renderer made the first draw into the second's context (its image lost
    the mesh, then was garbage once the second was released) and read back the second's buffers."""
    verts, tris = sphere()
    view = [Camera((0.0, -3.0, 1.0), (0.0, 0.0, 0.0))]

    def make(half):
        r = Renderer(96, 64, verts, ["grass"])
        part = tris[: len(tris) // 2] if half else tris
        r.apply(0, 0, len(part), part)
        return r, part
    first, part = make(True)
    alone = first.render(view)
    second, _ = make(False)                       # another mesh: the whole sphere
    try:
        assert np.array_equal(first.render(view), alone)
        assert np.array_equal(first.index_buffer(0, 0)[: len(part)], part)
        assert not np.array_equal(second.render(view), alone)
    finally:
        second.release()
    assert np.array_equal(first.render(view), alone), "after the second's release"
    first.release()
