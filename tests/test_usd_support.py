"""Helpers for the USD tests (the bundled scenes' Python data, small USD files written on the fly), and tests
of the pieces under the USD pipeline: size prediction (the memory guard) and the face map (uniform and
face-varying primvars)."""
import hashlib
import importlib.util
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES_DIR = os.path.join(ROOT, "scenes")


def scene_module():
    """scenes/make_scenes.py as a module (its SCENES hold every scene's meshes as plain data)."""
    name = "warp_subdiv_scene_data"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, os.path.join(SCENES_DIR, "make_scenes.py"))
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def digest(path) -> str:
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def grid(nx, ny, step=1.0):
    """A flat quad grid in the xy plane: points, counts, indices; face (i, j) is i + nx * j."""
    pts = np.array([(i * step, j * step, 0.0) for j in range(ny + 1) for i in range(nx + 1)], dtype=np.float64)
    faces = []
    for j in range(ny):
        for i in range(nx):
            v = i + (nx + 1) * j
            faces.append([v, v + 1, v + nx + 2, v + nx + 1])
    return pts, [4] * len(faces), [i for f in faces for i in f]


def write_mesh(path, points, counts, indices, *, prim="/World/Mesh", scheme="catmullClark", attrs=None,
               custom=None, time_points=None, setup=None):
    """A USD file with one mesh (under an Xform /World). ``attrs``: UsdGeom.Mesh attribute name -> value;
    ``custom``: name -> (Sdf type name, value); ``setup(stage, mesh)`` may author more."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, prim)
    mesh.CreateSubdivisionSchemeAttr(scheme)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in indices]))
    if time_points:
        for t, p in time_points.items():
            mesh.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(p, dtype=np.float32)), t)
    else:
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, dtype=np.float32)))
    for name, value in (attrs or {}).items():
        mesh.GetPrim().GetAttribute(name).Set(value)
    for name, (type_name, value) in (custom or {}).items():
        mesh.GetPrim().CreateAttribute(name, getattr(Sdf.ValueTypeNames, type_name), custom=True).Set(value)
    if setup is not None:
        setup(stage, mesh)
    stage.GetRootLayer().Save()
    return str(path)


def as_baked(refined):
    """``warp_subdiv.refine()``'s result numbered as the USD bake's default (``vertex_order="auto"``) writes it:
    the compact order (:class:`warp_subdiv.usd.order.OrderedRefiner`) for the piecewise-smooth rules, unchanged
    (OpenSubdiv's order) for rules="opensubdiv". ``limit_points()`` / ``limit_normals()`` follow the same order;
    ``refiner`` is the :class:`~warp_subdiv.usd.order.OrderedRefiner` (its ``evaluate``, ``evaluate_face_varying``
    return the bake's numbering too)."""
    import dataclasses

    from warp_subdiv.usd.order import OrderedRefiner

    if refined.rules == "opensubdiv":
        return refined
    ordered = OrderedRefiner(refined.refiner)
    counts, indices = ordered.topology()
    return dataclasses.replace(refined, points=ordered.compact(refined.points), face_vertex_counts=counts,
                               face_vertex_indices=indices, refiner=ordered)


# -- tests ---------------------------------------------------------------------------------------------
import pytest  # noqa: E402

import warp_subdiv as ws  # noqa: E402
from conftest import load_mesh  # noqa: E402
from warp_subdiv.runtime.estimate import BUILD_PEAK, LIMIT_PEAK, RUNTIME_BYTES, estimate, level_counts, parse_size, total_bytes  # noqa: E402
from warp_subdiv.errors import SubdivInputError  # noqa: E402
from warp_subdiv.tables.face_map import FaceMap  # noqa: E402


@pytest.mark.parametrize("name,scheme", [("cube", "catmull-clark"), ("mixed_prism", "catmull-clark"),
                                         ("quad_lshape", "catmull-clark"), ("icosahedron", "loop"),
                                         ("mixed_prism", "loop"), ("tri_hexfan", "loop")])
def test_predicted_counts_match_the_refiner(name, scheme):
    mesh = load_mesh(name)
    counts = level_counts(mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, 3, scheme)
    for level in (1, 2, 3):
        r = ws.Refiner(mesh, level, scheme=scheme, device="cpu")
        faces, indices = r.topology()
        assert (counts[level].vertices, counts[level].faces, counts[level].corners) == (
            r.num_vertices, len(faces), len(indices)), (name, scheme, level)


def test_estimate_grows_with_levels_and_samples():
    mesh = load_mesh("cube")
    one = estimate("cube", 8, mesh.face_vertex_counts, 12, 3, "catmull-clark")
    more = estimate("cube", 8, mesh.face_vertex_counts, 12, 4, "catmull-clark")
    frames = estimate("cube", 8, mesh.face_vertex_counts, 12, 3, "catmull-clark", samples=10)
    assert more.working_bytes > 3.5 * one.working_bytes
    assert frames.output_bytes > 9 * one.items["points"]
    # meshes are refined one after the other: outputs add up, working sets do not
    assert total_bytes([one, more]) == one.output_bytes + more.output_bytes + more.working_bytes + RUNTIME_BYTES
    # the working set: the control mesh analysis that stays, then the larger of the build peak and a frame's
    # evaluation per output vertex (tests/test_memory.py checks it against measurements)
    items = more.items
    assert items["refiner build"] == BUILD_PEAK["catmull-clark"][0] * more.final.vertices
    assert more.working_bytes == items["control mesh analysis"] + max(
        items["refiner build"], items["refiner kept"] + items["frame buffers"])
    projecting = estimate("cube", 8, mesh.face_vertex_counts, 12, 4, "catmull-clark", projecting=True)
    assert projecting.items["refiner build"] == BUILD_PEAK["catmull-clark"][1] * more.final.vertices
    assert projecting.working_bytes > 1.5 * more.working_bytes
    # limit masks: on the last level, or one level deeper (4x the vertices)
    limit = estimate("cube", 8, mesh.face_vertex_counts, 12, 4, "catmull-clark", limit=True)
    deeper = estimate("cube", 8, mesh.face_vertex_counts, 12, 4, "catmull-clark", limit=True, limit_deeper=True)
    assert limit.working_bytes - more.working_bytes == LIMIT_PEAK["catmull-clark"][0] * more.final.vertices
    assert deeper.items["limit masks"] > 3.9 * limit.items["limit masks"]  # 4x the vertices
    assert deeper.final.vertices == more.final.vertices


@pytest.mark.parametrize("text,expected", [("512M", 512 * 2**20), ("8G", 8 * 2**30), ("1.5GiB", int(1.5 * 2**30)),
                                           ("1000", 1000), ("none", None)])
def test_parse_size(text, expected):
    assert parse_size(text) == expected


@pytest.mark.parametrize("text", ["", "abc", "-1G", "5Q"])
def test_parse_size_refuses_nonsense(text):
    with pytest.raises(SubdivInputError, match="max_memory"):
        parse_size(text)


@pytest.mark.parametrize("name", ["mixed_prism", "quad_lshape", "icosahedron", "tri_hexfan", "grid3x3"])
@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("holes,boundary", [(False, "edge-and-corner"), (True, "edge-and-corner"), (False, "none")])
def test_face_map_follows_the_refiner(name, scheme, holes, boundary):
    """Linear per-corner data refined per face must agree wherever refined faces share a vertex, and the
    vertex children keep the control values: true only if the face map walks the refiner's child order."""
    m = load_mesh(name)
    if holes:
        m = ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, holes=[0])
    for level in (1, 2):
        r = ws.Refiner(m, level, scheme=scheme, boundary=boundary, device="cpu")
        counts, indices = r.topology()
        fmap = FaceMap(m, level, scheme, boundary)
        fmap.check(counts)
        per_corner = fmap.refine_corners(m.points[m.face_vertex_indices])
        assert per_corner.shape == (len(indices), 3)
        scattered = np.zeros((r.num_vertices, 3))
        scattered[indices] = per_corner
        np.testing.assert_allclose(scattered[indices], per_corner, atol=1e-12)
        used = np.zeros(r.num_vertices, bool)
        used[indices] = True
        old = np.flatnonzero(used[: m.num_vertices])
        np.testing.assert_allclose(scattered[old], m.points[old], atol=1e-12)
        # every refined face lies inside its parent: its corners are convex combinations of the parent's
        offsets = np.concatenate([[0], np.cumsum(counts)])
        centroid = np.add.reduceat(per_corner, offsets[:-1]) / counts[:, None]
        parent_pts = [m.points[m.face_vertex_indices[a:b]] for a, b in
                      zip(np.concatenate([[0], np.cumsum(m.face_vertex_counts)[:-1]]), np.cumsum(m.face_vertex_counts))]
        for f in range(0, len(counts), max(1, len(counts) // 40)):
            poly = parent_pts[fmap.parent[f]]
            lo, hi = poly.min(axis=0) - 1e-9, poly.max(axis=0) + 1e-9
            assert np.all(centroid[f] >= lo) and np.all(centroid[f] <= hi), (name, scheme, level, f)


def test_face_map_parent_at_level_one_is_the_face_point():
    """Catmull-Clark level 1: child quad of control face f contains the face point, vertex V + f."""
    m = load_mesh("mixed_prism")
    r = ws.Refiner(m, 1, device="cpu")
    counts, indices = r.topology()
    fmap = FaceMap(m, 1, "catmull-clark")
    quads = indices.reshape(-1, 4)
    assert np.all(np.any(quads == (m.num_vertices + fmap.parent)[:, None], axis=1))


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_face_map_agrees_with_the_refiners_linear_face_varying_channel(scheme):
    """Two implementations of linear face-varying refinement: the face map (used for bilinear meshes and
    varying primvars) and the refiner's face-varying channel in mode "all" on unshared corners."""
    m = load_mesh("mixed_prism")
    m = ws.Mesh(m.points, m.face_vertex_counts, m.face_vertex_indices, holes=[1])
    values = np.random.default_rng(3).normal(size=(len(m.face_vertex_indices), 2))
    r = ws.Refiner(m, 2, scheme=scheme, device="cpu", precision="float64")
    refined, indices = r.evaluate_face_varying(values, np.arange(len(values)), mode="all")
    np.testing.assert_allclose(np.asarray(refined)[indices], FaceMap(m, 2, scheme).refine_corners(values), atol=1e-12)
