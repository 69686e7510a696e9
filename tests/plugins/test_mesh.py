"""Mesh files in scenes: OBJ (the project's reader), PLY and glTF/GLB (through trimesh) with glTF tangents."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_lib.mesh import load_mesh, load_obj, mesh_vertex_radius
from sbrdf_lib.scene import SceneError, load_scene
from sbrdf_lib.surface import tessellate, vertex_frames
from sbrdf_render import materials as mat
from sbrdf_render.cpu import render_scene

from .test_models import REGISTRY
from .test_render import draw_gl, interior, relative_errors

trimesh = pytest.importorskip("trimesh", reason="the mesh extra (trimesh) reads PLY and glTF")


def write_glb(path: Path, positions, indices, normals=None, uvs=None, tangents=None, matrix=None) -> Path:
    """A minimal glTF 2.0 binary (``.glb``; ``.gltf``: JSON + ``.bin``): one mesh, one primitive, float32
    attributes, uint32 indices, one node.

    ``uvs`` are in sbrdf's (OBJ) convention and written as glTF's ``(u, 1 − v)``.
    """
    attrs = {"POSITION": np.asarray(positions, "<f4")}
    if normals is not None:
        attrs["NORMAL"] = np.asarray(normals, "<f4")
    if uvs is not None:
        uv = np.asarray(uvs, float)
        attrs["TEXCOORD_0"] = np.stack([uv[:, 0], 1 - uv[:, 1]], 1).astype("<f4")
    if tangents is not None:
        attrs["TANGENT"] = np.asarray(tangents, "<f4")
    blobs, views, accessors, prim = b"", [], [], {"attributes": {}}
    kinds = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
    for name, a in list(attrs.items()) + [("indices", np.asarray(indices, "<u4").ravel())]:
        data = a.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blobs), "byteLength": len(data)})
        acc = {"bufferView": len(views) - 1, "componentType": 5125 if name == "indices" else 5126, "count": len(a),
               "type": kinds[1 if a.ndim == 1 else a.shape[1]]}
        if name == "POSITION":
            acc |= {"min": a.min(0).tolist(), "max": a.max(0).tolist()}
        accessors.append(acc)
        blobs += data + b"\0" * (-len(data) % 4)
        if name == "indices":
            prim["indices"] = len(accessors) - 1
        else:
            prim["attributes"][name] = len(accessors) - 1
    node = {"mesh": 0} | ({"matrix": np.asarray(matrix, float).T.ravel().tolist()} if matrix is not None else {})
    header = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [node],
              "meshes": [{"primitives": [prim]}], "accessors": accessors, "bufferViews": views,
              "buffers": [{"byteLength": len(blobs)}]}
    if path.suffix == ".gltf":  # JSON with an external buffer beside it
        header["buffers"][0]["uri"] = path.with_suffix(".bin").name
        path.with_suffix(".bin").write_bytes(blobs)
        path.write_text(json.dumps(header))
        return path
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blobs), 0x004E4942) + blobs
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return path


def grid(n: int = 8, size: float = 2.0):
    """A flat n×n-quad grid on z = 0 (u along +x, v along +y) with per-vertex normals, uvs and uv-derived tangents."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    uv = np.stack([s.ravel(), t.ravel()], 1)
    pos = np.concatenate([(uv - 0.5) * size, np.zeros((len(uv), 1))], 1)
    a = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    idx = np.concatenate([np.stack([a, a + 1, a + n + 2], 1), np.stack([a, a + n + 2, a + n + 1], 1)])
    nrm, tan = vertex_frames(pos, uv, idx)
    return pos, uv, nrm, tan, idx


def write_obj(path: Path, pos, uv, idx, nrm=None) -> Path:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(pos).tolist()]
    lines += [f"vt {s!r} {t!r}" for s, t in np.asarray(uv).tolist()]
    lines += [f"vn {x!r} {y!r} {z!r}" for x, y, z in np.asarray(nrm).tolist()] if nrm is not None else []
    corner = "{0}/{0}/{0}" if nrm is not None else "{0}/{0}"
    lines += ["f " + " ".join(corner.format(i + 1) for i in f) for f in np.asarray(idx).tolist()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_glb_reads_positions_normals_uvs_tangents_and_node_transforms(tmp_path):
    pos, uv, nrm, tan, idx = grid(2)
    tan = tan.copy()
    tan[::2, 3] = -1  # the file's handedness is kept, not recomputed
    m = load_mesh(str(write_glb(tmp_path / "g.glb", pos, idx, nrm, uv, tan)))
    np.testing.assert_allclose(m.positions, pos, atol=1e-6)
    np.testing.assert_allclose(m.uvs, uv, atol=1e-6)  # back in the OBJ convention
    np.testing.assert_allclose(m.normals, nrm, atol=1e-6)
    np.testing.assert_array_equal(m.tangents[:, 3], tan[:, 3])
    np.testing.assert_array_equal(m.indices, idx)
    # a node transform moves positions, normals and tangents; a mirroring one flips winding and handedness
    rot = np.array([[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], float)
    r = load_mesh(str(write_glb(tmp_path / "r.glb", pos, idx, nrm, uv, tan, matrix=rot)))
    np.testing.assert_allclose(r.positions, pos @ rot[:3, :3].T + rot[:3, 3], atol=1e-6)
    np.testing.assert_allclose(r.tangents[:, :3], tan[:, :3] @ rot[:3, :3].T, atol=1e-6)
    mirror = np.diag([-1.0, 1, 1, 1])
    f = load_mesh(str(write_glb(tmp_path / "f.glb", pos, idx, nrm, uv, tan, matrix=mirror)))
    np.testing.assert_array_equal(f.indices, idx[:, ::-1])
    np.testing.assert_array_equal(f.tangents[:, 3], -tan[:, 3])
    assert mesh_vertex_radius(str(tmp_path / "r.glb")) == pytest.approx(np.linalg.norm(r.positions, axis=1).max())
    # .gltf with an external buffer reads the same; changing the buffer is seen (the cache follows it)
    g = load_mesh(str(write_glb(tmp_path / "t.gltf", pos, idx, nrm, uv, tan)))
    np.testing.assert_allclose(g.tangents, m.tangents)
    write_glb(tmp_path / "t.gltf", pos * 2, idx, nrm, uv, tan)
    np.testing.assert_allclose(load_mesh(str(tmp_path / "t.gltf")).positions, 2 * m.positions)
    # without TANGENT the renderers compute the frame from the uvs, as for OBJ
    plain = load_mesh(str(write_glb(tmp_path / "p.glb", pos, idx, uvs=uv)))
    assert plain.tangents is None and plain.normals is None


def test_ply_and_obj_load_the_same_triangles(tmp_path):
    pos, uv, nrm, _, idx = grid(3)
    ply = tmp_path / "g.ply"
    trimesh.Trimesh(pos, idx, vertex_normals=nrm, process=False,
                    visual=trimesh.visual.TextureVisuals(uv=uv)).export(str(ply))
    obj = write_obj(tmp_path / "g.obj", pos, uv, idx, nrm)
    p, o = load_mesh(str(ply)), load_mesh(str(obj))
    np.testing.assert_array_equal(p.indices, idx)  # PLY keeps the file's vertices; OBJ numbers corners by first use
    for a, b in ((p.positions, o.positions), (p.uvs, o.uvs), (p.normals, o.normals)):
        np.testing.assert_allclose(a[p.indices], b[o.indices], atol=1e-6)  # the same corners, triangle by triangle
    # an ASCII PLY quad with s, t coordinates: triangulated, uvs kept, no normals
    quad = tmp_path / "quad.ply"
    quad.write_text("ply\nformat ascii 1.0\nelement vertex 4\n" + "".join(f"property float {k}\n" for k in "xyzst")
                    + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0 0 0\n1 0 0 1 0\n1 1 0 1 1\n0 1 0 0 1\n4 0 1 2 3\n")
    q = load_mesh(str(quad))
    assert q.indices.shape == (2, 3) and q.normals is None
    np.testing.assert_array_equal(q.uvs, q.positions[:, :2])
    # trimesh reads the same OBJ to the same triangles (its vertex order may differ: the project's reader is kept)
    t = trimesh.load(str(obj), force="mesh", process=False, maintain_order=True)
    np.testing.assert_allclose(np.sort(t.vertices[t.faces].reshape(-1, 3), 0),
                               np.sort(o.positions[o.indices].reshape(-1, 3), 0), atol=1e-12)


def test_broken_and_unsupported_mesh_files_are_scene_errors_naming_file_and_line(tmp_path):
    (tmp_path / "bad.glb").write_bytes(b"glTF\x02\0\0\0garbage that is not a GLB")
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n")
    (tmp_path / "cloud.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                                        "property float z\nend_header\n0 0 0\n")
    (tmp_path / "m.stl").write_text("solid x\nendsolid x\n")
    for name, needle in (("bad.glb", "bad.glb"), ("bad.ply", "not a readable PLY file"), ("cloud.ply", "no faces"),
                         ("m.stl", "unsupported format '.stl'")):
        path = tmp_path / "s.yaml"
        path.write_text(f"""camera: {{position: [0, -2, 2]}}
materials: {{m: {{model: lambert, params: {{rho: 0.5}}}}}}
objects:
  - {{shape: plane, material: m}}
  - {{shape: mesh, file: {name}, material: m}}
lights: [{{type: point, position: [0, 0, 2]}}]
""")
        with pytest.raises(SceneError) as e:
            load_scene(str(path))
        assert "s.yaml:5:" in str(e.value) and name in str(e.value) and needle in str(e.value), str(e.value)
    with pytest.raises(SbrdfError, match="unsupported mesh format"):
        load_mesh(str(tmp_path / "m.stl"))


SCENE = """camera: {{position: [0, -1.6, 1.7], look_at: [0, 0, 0], fov_deg: 55, resolution: [80, 60]}}
materials: {{m: {{model: ward, model_params: {{anisotropic: true}},
               params: {{rho_d: 0.05, rho_s: 0.4, alpha_x: 0.06, alpha_y: 0.35}}}}}}
objects: [{{shape: mesh, file: {file}, material: m}}]
lights: [{{type: point, position: [0, 0.5, 1.2], intensity: 3}}]
"""
PARAMS = {"rho_d": 0.05, "rho_s": 0.4, "alpha_x": 0.06, "alpha_y": 0.35}


def render_glb(tmp_path, name, tangents, gl=None):
    """cpu (and gl) renders of the 8×8 grid written as a GLB with these tangents (None: computed from the uvs)."""
    pos, uv, nrm, _, idx = grid(8)
    glb = write_glb(tmp_path / name, pos, idx, nrm, uv, tangents)
    assert glb.stat().st_size < 50_000
    scene = load_scene(SCENE.format(file=glb))
    materials = {"m": mat.uniform("m", REGISTRY.create("brdf-model", "ward", {"anisotropic": True}), PARAMS)}
    ref, _ = render_scene(scene, materials)
    got = draw_gl(gl, scene, materials)[0] if gl is not None else None
    return scene, materials, ref, got


def tangents(angle_deg: float, w: float = 1.0, n: int = 81) -> np.ndarray:
    a = np.radians(angle_deg)
    return np.tile([np.cos(a), np.sin(a), 0.0, w], (n, 1))


def test_cpu_and_gl_render_a_glb_mesh_with_its_tangents(gl, tmp_path):
    """Tangents at 30° to the uv's +u, handedness −1: the highlight follows the file's frame, and both renderers agree."""
    scene, materials, ref, got = render_glb(tmp_path, "t.glb", tangents(30, w=-1), gl)
    assert np.isfinite(ref).all() and ref.max() > 0.05
    mask = interior(scene, materials)
    rel = relative_errors(got, ref, mask)
    assert np.sqrt(np.mean(rel**2)) < 1e-3
    # the same surface with uv-derived tangents (+x) shades differently: the file's tangents are used
    _, _, uvref, _ = render_glb(tmp_path, "uv.glb", None)
    assert np.abs(uvref - ref)[mask].max() > 0.05 * ref[mask].max()


def test_tangent_frames_follow_the_file_and_mirrored_tangents_mirror_the_highlight(tmp_path):
    """B = w · N × T with the file's w; tangents mirrored about the camera's plane of symmetry (x = 0) mirror the
    anisotropic highlight left-right.  Flipping w alone turns B to −B, which an anisotropic Ward lobe (a function of
    (h·T)² and (h·B)²) cannot see: that image is unchanged, as it must be."""
    scene, materials, a, _ = render_glb(tmp_path, "plus.glb", tangents(30))
    for w in (1.0, -1.0):
        m = tessellate(load_scene(SCENE.format(file=write_glb(tmp_path / "w.glb", *grid(8)[:1], grid(8)[4], grid(8)[2],
                                                              grid(8)[1], tangents(30, w)))).objects[0])
        bit = m.tangents[:, 3:4] * np.cross(m.normals, m.tangents[:, :3])
        np.testing.assert_allclose(bit, w * np.tile([-0.5, np.sqrt(0.75), 0.0], (81, 1)), atol=1e-6)
    _, _, b, _ = render_glb(tmp_path, "minus.glb", tangents(-30))
    mask = interior(scene, materials) & interior(scene, materials)[:, ::-1]
    assert np.abs(a - b)[mask].max() > 0.1 * a[mask].max()  # not trivially symmetric
    np.testing.assert_allclose(a[mask], b[:, ::-1][mask], rtol=1e-6, atol=1e-9 * a.max())
    _, _, c, _ = render_glb(tmp_path, "flipped.glb", tangents(30, w=-1))
    np.testing.assert_allclose(c, a, rtol=1e-9, atol=1e-12)


def test_obj_scene_renders_as_before(tmp_path):
    """OBJ keeps the project's reader: a scene's mesh is the corner table of :func:`load_obj`, unchanged."""
    pos, uv, nrm, _, idx = grid(2)
    obj = write_obj(tmp_path / "g.obj", pos, uv, idx)
    scene = load_scene(SCENE.format(file=obj))
    p, u, _, i = load_obj(str(obj))
    m = tessellate(scene.objects[0])
    np.testing.assert_array_equal(m.positions, p)
    np.testing.assert_array_equal(m.indices, i)
    np.testing.assert_array_equal(m.uvs, u)


SHIPPED = Path(__file__).resolve().parents[2] / "scenes"


def brushed_disc(rings: int = 8, segments: int = 40, inner: float = 0.15):
    """An annulus of radius 1 (a CD), uv = the planar xy map, tangents around the circles: radial brushing.

    Its uv-derived tangents would all point along +x; the file's carry the brushing direction."""
    r, phi = np.meshgrid(np.linspace(inner, 1.0, rings + 1), np.linspace(0, 2 * np.pi, segments + 1))
    r, phi = r.ravel(), phi.ravel()
    pos = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros_like(r)], 1)
    uv = (pos[:, :2] + 1) / 2
    nrm = np.tile([0.0, 0.0, 1.0], (len(r), 1))
    tan = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(r), np.ones_like(r)], 1)
    a = (np.arange(segments)[:, None] * (rings + 1) + np.arange(rings)[None, :]).ravel()
    idx = np.concatenate([np.stack([a, a + rings + 1, a + rings + 2], 1), np.stack([a, a + rings + 2, a + 1], 1)])
    return pos, uv, nrm, tan, idx


def test_shipped_brushed_disc_scene_is_reproducible_and_renders(gl, tmp_path):
    """scenes/brushed-disc.glb is what :func:`brushed_disc` writes (so it can be regenerated), under 50 kB; the
    scene renders through cpu and gl alike, with the ring-shaped highlight of its tangents."""
    pos, uv, nrm, tan, idx = brushed_disc()
    fresh = write_glb(tmp_path / "disc.glb", pos, idx, nrm, uv, tan)
    glb = SHIPPED / "brushed-disc.glb"
    assert glb.read_bytes() == fresh.read_bytes() and glb.stat().st_size < 50_000
    scene = load_scene(str(SHIPPED / "brushed-disc.yaml"))
    ref_scene = scene.materials["brushed"]
    materials = {"brushed": mat.uniform("brushed", REGISTRY.create("brdf-model", ref_scene.model,
                                                                   dict(ref_scene.model_params)), ref_scene.params)}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    assert np.isfinite(ref).all() and ref.max() > 0.05
    rel = relative_errors(got, ref, interior(scene, materials))
    assert np.sqrt(np.mean(rel**2)) < 1e-3
