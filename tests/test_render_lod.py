"""The renderer fed by the refinement core, as a thin client would be.

* At 0 px tolerance without culling the LOD image is the original mesh's
  image, pixel for pixel.
* At 1 px tolerance the images differ only along edges, slightly.
* Patching the GPU index buffers in place over a long walk gives exactly
  what uploading them whole gives, for a fraction of the bytes, and the GPU
  holds what the client holds after every frame.
"""

import numpy as np
import pytest

import caveclod
from caveclod import paths
from caveclod.api import to_source
from caveclod.builder.hierarchy import build_static_mesh
from caveclod.builder.surfaces import corner_vertices
from caveclod.render import Renderer, Vertices
from caveclod.render.renderer import BACKGROUND

SKY = np.round(np.array(BACKGROUND) * 255).astype(np.uint8)
MESHES = {"terrain": ("default", 48), "rough": ("rough", 48), "scan": ("scan", 40)}


class Mesh:
    """A built-in mesh with its original triangles as vertex-buffer indices."""

    def __init__(self, name: str, size: int):
        source = to_source(name, size=size)
        self.mesh = build_static_mesh(source)
        m = self.mesh
        # The D3Dindex lookup of every original corner (as tests/test_camera.py does).
        self.original = corner_vertices(np.asarray(m.pos_vstart), np.asarray(m.vertex_sgid),
                                        source.face_positions.astype(np.int64), np.asarray(m.face_sgid))
        assert (self.original >= 0).all()
        self.face_material = np.asarray(m.face_material)
        self.vertices = Vertices(m.vertex_positions, m.vertex_normals, m.vertex_uvs,
                                 m.vertex_colors if len(m.vertex_colors) else None)
        self.lo, self.hi = m.bounds()
        self.object = name == "scan"

    def pose(self, camera: int, t: float) -> paths.Pose:
        """Terrains: the paper's flyover. The scan: in front of its scanned
        (+y) side (camera 3 of ``line``, or 1, behind it), between 0.6 and
        1.16 of its width from its centre, in and out every 16 s."""
        if self.object:
            return paths.line(self.lo, self.hi, 3 if camera % 2 == 0 else 1, 12.0 + t % 16.0)
        return paths.flyover(self.lo, self.hi, camera, t)

    def renderer(self, gl, width, height, cameras=1) -> Renderer:
        return Renderer(width, height, self.vertices, self.mesh.materials, cameras=cameras, ctx=gl)

    def original_of(self, material: int) -> np.ndarray:
        return self.original[self.face_material == material].astype(np.uint32)


@pytest.fixture(scope="module", params=sorted(MESHES))
def built(request):
    return Mesh(*MESHES[request.param])


def view(pose, width, height, tolerance_px, cull=True):
    return caveclod.View.from_pose(pose, width=width, height=height, tolerance_px=tolerance_px, cull=cull)


def feed(renderer: Renderer, camera: int, delta) -> None:
    """Apply a core :class:`caveclod.Delta` the way a frame's SurfaceDeltas arrive."""
    for material, d in delta.surfaces.items():
        renderer.apply(camera, material, d.count, d.tris, slots=d.slots)


def keyframe(renderer: Renderer, camera: int, cam) -> None:
    """A keyframe: every buffer emptied, then written whole from slot 0."""
    renderer.reset(camera)
    for material, tris in cam.triangles().items():
        renderer.apply(camera, material, len(tris), tris, first_slot=0)


def image_stats(a: np.ndarray, b: np.ndarray) -> dict:
    diff = np.abs(a.astype(np.int64) - b)
    mse = float((diff ** 2).mean())
    return {"fraction_differing": float((diff.max(axis=-1) > 0).mean()), "mean_abs_diff": float(diff.mean()),
            "psnr_db": float("inf") if mse == 0 else float(10.0 * np.log10(255.0 ** 2 / mse)),
            "max_diff": int(diff.max())}


# -- 0 px: the original mesh exactly ----------------------------------------------

def test_full_refinement_renders_the_original_mesh_pixel_for_pixel(gl, built):
    """The core's fully refined buffers hold every original face once, each
    with the source's corners in the source's order, but in slot orders of
    their own. Depth testing makes the slot order irrelevant: on a mesh whose
    faces do not overlap, each pixel is won by the one face covering it
    (shared edges go to one side by the rasteriser's fill rule), whatever the
    drawing order. So the LOD image must equal, bit for bit, the image of
    the original faces uploaded as the source stores them."""
    W, H = 240, 180
    mesh = built.mesh
    cam = mesh.new_camera()
    with built.renderer(gl, W, H) as lod, built.renderer(gl, W, H) as original_mesh:
        keyframe(lod, 0, cam)                                    # the base mesh first
        for m in range(mesh.n_materials):
            original = built.original_of(m)
            original_mesh.apply(0, m, len(original), original)
        for t in (2.0, 11.0, 19.0):
            pose = built.pose(0, t)
            feed(lod, 0, cam.update(view(pose, W, H, tolerance_px=0.0, cull=False)))
            for m in range(mesh.n_materials):
                # The same rows, corner for corner, in another order.
                on_gpu, original = lod.index_buffer(0, m), built.original_of(m)
                np.testing.assert_array_equal(np.unique(on_gpu, axis=0), np.unique(original, axis=0))
                assert len(on_gpu) == len(original)
            image = lod.render([pose])
            assert (np.abs(image.astype(int) - SKY) > 1).any(axis=-1).mean() > 0.2   # the mesh is in view
            np.testing.assert_array_equal(image, original_mesh.render([pose]))


# -- 1 px: slightly different ------------------------------------------------------------

def edge_band(image: np.ndarray, step: int = 24, width: int = 2) -> np.ndarray:
    """(h, w) bool: pixels within ``width`` of a colour step > ``step`` levels
    (silhouettes, material borders, strong texture detail)."""
    img = image.astype(np.int64)
    band = np.zeros(img.shape[:2], bool)
    dy = np.abs(np.diff(img, axis=0)).max(axis=-1) > step
    dx = np.abs(np.diff(img, axis=1)).max(axis=-1) > step
    band[1:] |= dy
    band[:-1] |= dy
    band[:, 1:] |= dx
    band[:, :-1] |= dx
    for _ in range(width):
        grown = band.copy()
        grown[1:] |= band[:-1]
        grown[:-1] |= band[1:]
        grown[:, 1:] |= band[:, :-1]
        grown[:, :-1] |= band[:, 1:]
        band = grown
    return band


def test_one_pixel_tolerance_differs_slightly(gl, built):
    """At 1 px every point of the LOD surface is within a pixel of where the
    original puts it on screen, so a pixel can change colour outright only
    where something else lies within a pixel: along silhouettes and texture
    or material borders. Elsewhere only shading drifts (normals interpolated
    over larger triangles). Asserted: pixels more than 32 levels off lie
    within 2 px of such an edge of the original image (1 px of error, 1 of
    rasterisation), but for 0.05 % of the image; PSNR >= 35 dB; and the LOD
    really is coarser (at most 65 % of the faces)."""
    W, H = 320, 240
    mesh = built.mesh
    with built.renderer(gl, W, H) as lod, built.renderer(gl, W, H) as original:
        for m in range(mesh.n_materials):
            tris = built.original_of(m)
            original.apply(0, m, len(tris), tris)
        for t in (1.0, 9.0, 14.0):
            pose = built.pose(2, t)
            cam = mesh.new_camera()
            cam.update(view(pose, W, H, tolerance_px=1.0))
            keyframe(lod, 0, cam)
            a, b = lod.render([pose]), original.render([pose])
            stats = image_stats(a, b)
            strong = np.abs(a.astype(np.int64) - b).max(axis=-1) > 32
            off_edges = float((strong & ~edge_band(b)).mean())
            print(f"\n1 px, t={t}: {cam.n_faces} of {mesh.n_faces} faces; {stats}; "
                  f"> 32 levels: {strong.mean():.4%}, of which off edges: {off_edges:.4%}")
            # Coarser, not the original redrawn: the small scan draws 50-60 % of its faces here
            # (57 % before new edges were measured at up to 7 points), the terrains 10-36 %.
            assert cam.n_faces <= 0.65 * mesh.n_faces
            assert 0 < stats["fraction_differing"] and stats["psnr_db"] >= 35.0
            assert off_edges <= 0.0005


# -- patching in place over a long walk ---------------------------------------------------------

def test_patching_in_place_equals_uploading_whole_over_a_long_walk(gl, built):
    """Two cameras, 150 frames: camera 0 flies its path; camera 1, under an
    operations budget (partial updates), jumps to a random pose every 12
    frames and moves on from there; at frame 75 camera 1 is re-sent as a
    keyframe (a client that asked for one). Renderer ``patched`` gets the
    deltas; ``whole`` gets every buffer re-uploaded from slot 0 each frame.
    After every frame: the GPU buffers equal the client's numpy buffers
    (``Delta.apply``) and the core's ``triangles()``, and the two images are
    identical."""
    W, H, frames = 160, 96, 150
    mesh = built.mesh
    rng = np.random.default_rng(3)
    cams = [mesh.new_camera(), mesh.new_camera(max_ops=150)]
    client = [{}, {}]
    with built.renderer(gl, W, H, cameras=2) as patched, built.renderer(gl, W, H, cameras=2) as whole:
        for k, cam in enumerate(cams):
            base = cam.keyframe()
            base.apply(client[k])
            feed(patched, k, base)
        jump = (1, 0.0)
        for frame in range(frames):
            if frame % 12 == 0:
                jump = (int(rng.integers(0, 4)), float(rng.uniform(0.0, 60.0)))
            poses = [built.pose(0, 0.2 * frame), built.pose(jump[0], jump[1] + 0.1 * (frame % 12))]
            for k, (cam, pose) in enumerate(zip(cams, poses)):
                delta = cam.update(view(pose, W // 2, H, tolerance_px=1.0))
                delta.apply(client[k])
                if k == 1 and frame == 75:
                    keyframe(patched, k, cam)
                else:
                    feed(patched, k, delta)
                keyframe(whole, k, cam)
                core = cam.triangles()
                for m in range(mesh.n_materials):
                    on_gpu = patched.index_buffer(k, m)
                    np.testing.assert_array_equal(on_gpu, client[k].get(m, np.zeros((0, 3), np.uint32)))
                    np.testing.assert_array_equal(on_gpu, core.get(m, np.zeros((0, 3), np.uint32)))
            np.testing.assert_array_equal(patched.render(poses), whole.render(poses))
        p, w = patched.stats, whole.stats
        print(f"\n{frames} frames, 2 cameras: patched {p.index_bytes:,} B in {p.index_writes:,} writes "
              f"({p.grows} grows, {p.gpu_copy_bytes:,} B copied on the GPU); "
              f"whole {w.index_bytes:,} B in {w.index_writes:,} writes: {w.index_bytes / p.index_bytes:.1f} x")
        assert p.vertex_bytes == w.vertex_bytes == mesh.n_vertices * (32 + (4 if built.vertices.colors is not None
                                                                         else 0))
        assert p.index_bytes * 5 < w.index_bytes
        assert p.grows > 0 and p.gpu_copy_bytes > 0
