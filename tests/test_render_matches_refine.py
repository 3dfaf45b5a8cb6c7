"""`render --levels N` previews what `refine --levels N` bakes: both front ends build their refiner through the
same path (warp_subdiv.usd.make_refiner), so every option a file asks for reaches the preview too."""
import numpy as np
import pytest
from pxr import Usd, UsdGeom, Vt

from test_usd_support import grid, write_mesh

LEVELS = 2


def fan_corners(points, counts, indices):
    """World-space corners of the fan triangles (v0, vi, vi+1) of every face, face by face, as the renderer
    triangulates (the meshes of these tests sit under an untransformed /World)."""
    points = np.asarray(points, dtype=np.float64)
    indices = np.asarray(indices, dtype=np.int64)
    out, start = [], 0
    for c in np.asarray(counts, dtype=np.int64):
        for i in range(1, c - 1):
            out.extend([indices[start], indices[start + i], indices[start + i + 1]])
        start += c
    return points[np.asarray(out, dtype=np.int64)]


def rendered_soup(monkeypatch, args):
    """Run `warp-subdiv render ARGS` in this process and return the triangle soup it would ray-cast."""
    from warp_subdiv import cli
    from warp_subdiv import render

    seen = {}

    def capture(soup, camera, width, height, samples=2, device=None, edges=None):
        seen["soup"] = soup
        return np.zeros((height, width, 3), dtype=np.uint8)

    monkeypatch.setattr(render, "render_soup", capture)
    assert cli.main(args) == 0
    return seen["soup"]


def mixed_scene(path):
    """One Catmull-Clark mesh of quads and triangles (a 3x3 grid, its middle quad split), not flat, asking
    for flatness, normal control at an interior vertex and the smooth triangle rule."""
    pts, counts, idx = grid(3, 3)
    pts = np.array(pts, dtype=np.float64)
    pts[:, 2] = 0.3 * np.sin(1.7 * pts[:, 0]) * np.cos(1.3 * pts[:, 1])
    faces = [idx[4 * f:4 * f + 4] for f in range(len(counts))]
    a, b, c, d = faces[4]
    faces[4:5] = [[a, b, c], [a, c, d]]
    counts = [len(f) for f in faces]
    indices = [v for f in faces for v in f]
    normal = np.array([0.3, -0.2, 0.9])
    normal /= np.linalg.norm(normal)
    return write_mesh(path, pts, counts, indices, attrs={"triangleSubdivisionRule": "smooth"}, custom={
        "subdiv:flatness": ("Float", 0.8),
        "subdiv:normalStrength": ("Float", 0.5),
        "subdiv:normalIndices": ("IntArray", Vt.IntArray([5])),
        "subdiv:normals": ("Normal3fArray", Vt.Vec3fArray([tuple(map(float, normal))])),
    })


def test_usd_preview_refines_as_the_bake(tmp_path, monkeypatch):
    """render --levels and refine --levels give the same points for a mesh with subdiv:flatness,
    subdiv:normalStrength, prescribed normals and triangleSubdivisionRule "smooth" (the preview used to
    drop all three)."""
    from warp_subdiv import cli

    src = mixed_scene(tmp_path / "mixed.usda")
    baked = tmp_path / "baked.usda"
    assert cli.main(["refine", src, "-o", str(baked), "--levels", str(LEVELS), "--device", "cpu", "--quiet"]) == 0
    stage = Usd.Stage.Open(str(baked))  # kept: a prim does not keep its stage alive
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    expected = fan_corners(mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get(),
                           mesh.GetFaceVertexIndicesAttr().Get())
    soup = rendered_soup(monkeypatch, ["render", src, "-o", str(tmp_path / "preview.png"), "--levels", str(LEVELS),
                                       "--device", "cpu", "--size", "8x6", "--samples", "1"])
    assert soup.corners.shape == expected.shape
    np.testing.assert_allclose(soup.corners, expected, atol=1e-6)


def test_the_options_each_make_a_difference(tmp_path):
    """The scene above is a real check: each option it asks for moves the refined points."""
    from warp_subdiv.usd import make_refiner, options_for
    from warp_subdiv.io.usd_read import read_mesh
    from warp_subdiv.io.usd_stage import open_stage

    stage = open_stage(mixed_scene(tmp_path / "mixed.usda"))
    sp = read_mesh(stage.GetPrimAtPath("/World/Mesh"))
    options = options_for(sp)
    assert (options.flatness, options.normal_strength, options.triangle_subdivision) == (
        pytest.approx(0.8), pytest.approx(0.5), "smooth")
    full = make_refiner(sp, LEVELS, options=options, device="cpu").evaluate(sp.points_default)
    for change in ({"flatness": None}, {"normal_strength": 1.0}, {"triangle_subdivision": "catmark"}):
        other = make_refiner(sp, LEVELS, options=options.replace(**change), device="cpu").evaluate(sp.points_default)
        assert np.abs(other - full).max() > 1e-4, change


def test_obj_preview_refines_as_the_bake(tmp_path, monkeypatch):
    """render --levels and refine --levels agree on OBJ input too, the file's interpolateboundary tag included
    (the preview used to ignore it)."""
    from warp_subdiv import cli
    from warp_subdiv.io.obj import read_obj

    pts, counts, idx = grid(2, 2)
    pts = np.array(pts, dtype=np.float64)
    pts[4, 2] = 0.7
    src = tmp_path / "plate.obj"
    lines = [f"v {x} {y} {z}" for x, y, z in pts]
    lines += ["f " + " ".join(str(v + 1) for v in idx[4 * f:4 * f + 4]) for f in range(len(counts))]
    lines.append("t interpolateboundary 1/0/0 2")  # edge-only: the plate's corners are not kept
    src.write_text("\n".join(lines) + "\n")
    baked = tmp_path / "baked.obj"
    assert cli.main(["refine", str(src), "-o", str(baked), "--levels", str(LEVELS), "--device", "cpu",
                     "--quiet"]) == 0
    out = read_obj(str(baked)).mesh
    expected = fan_corners(out.points, out.face_vertex_counts, out.face_vertex_indices)
    soup = rendered_soup(monkeypatch, ["render", str(src), "-o", str(tmp_path / "preview.png"), "--levels",
                                       str(LEVELS), "--device", "cpu", "--size", "8x6", "--samples", "1"])
    np.testing.assert_allclose(soup.corners, expected, atol=1e-6)
    assert np.abs(out.points[0] - pts[0]).max() > 0.05  # edge-only: the plate's corner (vertex 0) moved in
