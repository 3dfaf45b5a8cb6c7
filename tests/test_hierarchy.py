"""The hierarchy's recorded parentage (child-to-parent maps of faces, edges and vertices, the rotation of child
corners, the composition down to the control mesh) against brute force on small meshes."""
import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh
from warp_subdiv.tables.hierarchy import Hierarchy, Parentage
from warp_subdiv.options import Options
from warp_subdiv.tables.face_map import FaceMap
from warp_subdiv.topology import EDGE, FACE, VERTEX, Refinement, base_level, refine_level


def polygons():
    """An open mesh of a pentagon, a hexagon, a quad and a triangle (non-quads in both schemes)."""
    pts = np.array([[0, 0, 0], [2, 0, 0], [3, 1.5, 0], [1, 2.5, 0], [-1, 1.5, 0], [4.5, 2.5, 0], [4, 4, 0],
                    [2, 4.5, 0], [0.5, 4, 0], [4, 0, 0]], dtype=float)
    counts = [5, 6, 4, 3]
    indices = [0, 1, 2, 3, 4, 3, 2, 5, 6, 7, 8, 1, 9, 5, 2, 4, 3, 8]
    return ws.Mesh(pts, counts, indices)


def mesh_of(name, holes=False):
    mesh = polygons() if name == "polygons" else load_mesh(name)
    if holes:
        mesh = ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, holes=[0])
    return mesh


CASES = [(name, scheme, holes, boundary)
         for name in ("cube", "mixed_prism", "quad_lshape", "polygons", "icosahedron", "tri_grid3x3")
         for scheme in ("catmull-clark", "loop")
         for holes, boundary in ((False, "edge-and-corner"), (True, "edge-and-corner"), (False, "none"))]


def brute_levels(mesh, levels, options):
    """Every level's full topology, refined from scratch."""
    level = base_level(mesh, options.scheme, options.boundary, options.rules, options.triangulate,
                       crease_method=options.crease_method, linear=options.linear)
    out = [level]
    for _ in range(levels):
        level = refine_level(level)
        out.append(level)
    return out


def faces_of(level):
    """Every face's corners as a list of corner ids."""
    starts, sizes = level.face_starts(), level.face_sizes()
    return [np.arange(s, s + n) for s, n in zip(starts, sizes)]


@pytest.mark.parametrize("name,scheme,holes,boundary", CASES)
def test_child_faces_hold_the_children_of_their_parent_face_in_the_recorded_rotation(name, scheme, holes, boundary):
    """Each child face's vertices are children of its parent face's vertices, edges and the face itself, and
    sit where the recorded slot and rotation say: [vertex child, child of the edge leaving the corner, face child
    (Catmull-Clark), child of the edge entering it] from position r on; Loop's middle child holds the child of
    edge m + 1 at position m."""
    mesh = mesh_of(name, holes)
    options = Options(scheme=scheme, boundary=boundary)
    h = Hierarchy(mesh, 2, options)
    levels = brute_levels(mesh, 2, options)
    for k in (1, 2):
        parent, child = levels[k - 1], levels[k]
        face, slot = h.face_parent(k)
        rot = h.face_rotation(k)
        kind, index = h.vertex_parent(k)
        assert len(face) == child.num_faces and len(kind) == child.num_vertices
        n = child.face_size
        cv = child.corner_vert.reshape(-1, n).astype(np.int64)
        V, F = parent.num_vertices, parent.num_faces
        edge_base = V + F if scheme == "catmull-clark" else V
        parent_faces = faces_of(parent)
        for c in range(child.num_faces):
            corners = parent_faces[face[c]]
            # generic: every vertex of the child is a child of an element of the parent face
            elements = {(VERTEX, int(v)) for v in parent.corner_vert[corners]}
            elements |= {(EDGE, int(e)) for e in parent.corner_edge[corners]}
            elements.add((FACE, int(face[c])))
            assert {(int(kind[v]), int(index[v])) for v in cv[c]} <= elements, (k, c)
            # exact: the child's corners in the recorded rotation
            j = int(slot[c])
            if scheme == "loop" and j == 3:
                expected = [edge_base + parent.corner_edge[corners[(m + 1) % 3]] for m in range(3)]
            else:
                hc, hp = corners[j], corners[(j - 1) % len(corners)]
                expected = [parent.corner_vert[hc], edge_base + parent.corner_edge[hc]]
                if scheme == "catmull-clark":
                    expected.append(V + face[c])
                expected.append(edge_base + parent.corner_edge[hp])
            assert np.array_equal(np.roll(expected, int(rot[c])), cv[c]), (k, c, expected, cv[c], rot[c])


@pytest.mark.parametrize("name,scheme,holes,boundary", CASES[::2])
def test_child_edges_join_children_of_their_parent_element(name, scheme, holes, boundary):
    """Edge h < C lies in the face of parent corner h between its face child (or the child of the entering
    edge, Loop) and the child of the leaving edge; edge C + 2e + s joins the child of e's end s to e's child."""
    mesh = mesh_of(name, holes)
    options = Options(scheme=scheme, boundary=boundary)
    h = Hierarchy(mesh, 2, options)
    levels = brute_levels(mesh, 2, options)
    for k in (1, 2):
        parent, child = levels[k - 1], levels[k]
        kind, index, slot = h.edge_parent(k)
        assert len(kind) == child.num_edges
        V, F = parent.num_vertices, parent.num_faces
        edge_base = V + F if scheme == "catmull-clark" else V
        starts, sizes = parent.face_starts(), parent.face_sizes()
        ev = parent.edge_verts.astype(np.int64)
        for e in range(child.num_edges):
            got = sorted(child.edge_verts[e].tolist())
            if kind[e] == FACE:
                f, j = int(index[e]), int(slot[e])
                hc = starts[f] + j
                hp = starts[f] + (j - 1) % sizes[f]
                other = V + f if scheme == "catmull-clark" else edge_base + parent.corner_edge[hp]
                assert got == sorted([int(other), int(edge_base + parent.corner_edge[hc])]), (k, e)
            else:
                assert kind[e] == EDGE
                pe, s = int(index[e]), int(slot[e])
                assert got == sorted([int(ev[pe, s]), int(edge_base + pe)]), (k, e)


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
@pytest.mark.parametrize("name,boundary", [("polygons", "edge-and-corner"), ("mixed_prism", "edge-and-corner"),
                                           ("quad_lshape", "none")])
def test_vertex_children_sit_at_their_parents_under_bilinear_refinement(name, scheme, boundary):
    """Under bilinear refinement (``linear=True``) a vertex child keeps its parent's position, an edge child
    is the edge's midpoint and a face child the face's centroid: the vertex parent map names the right one."""
    mesh = mesh_of(name)
    options = Options(scheme=scheme, boundary=boundary, linear=True, precision="float64")
    levels = brute_levels(mesh, 2, options)
    points = [mesh.points]
    for k in (1, 2):
        points.append(ws.Refiner(mesh, k, options=options, device="cpu").evaluate(mesh.points))
    h = Hierarchy(mesh, 2, options)
    for k in (1, 2):
        parent, before, after = levels[k - 1], points[k - 1], points[k]
        kind, index = h.vertex_parent(k)
        expected = np.empty_like(after)
        expected[kind == VERTEX] = before[index[kind == VERTEX]]
        ev = parent.edge_verts.astype(np.int64)[index[kind == EDGE]]
        expected[kind == EDGE] = 0.5 * (before[ev[:, 0]] + before[ev[:, 1]])
        if np.any(kind == FACE):
            centroid = np.array([before[parent.corner_vert[c]].mean(axis=0) for c in faces_of(parent)])
            expected[kind == FACE] = centroid[index[kind == FACE]]
        np.testing.assert_allclose(after, expected, atol=1e-12)


@pytest.mark.parametrize("name,scheme,holes,boundary", CASES)
def test_control_faces_compose_the_parent_maps_and_equal_the_face_map(name, scheme, holes, boundary):
    """control_face_of composes face_parent step by step (and Loop's triangulation); without its hole faces it
    is FaceMap.parent, whether the face map reads the hierarchy or derives the parentage from the mesh."""
    mesh = mesh_of(name, holes)
    r = ws.Refiner(mesh, 2, scheme=scheme, boundary=boundary, device="cpu")
    h = r.hierarchy
    levels = brute_levels(mesh, 2, r.options)
    tri_parent = levels[0].control_face
    composed = np.arange(levels[0].num_faces)
    for k in (1, 2):
        face, _ = h.face_parent(k)
        composed = composed[face]
        control = composed if tri_parent is None else tri_parent[composed]
        np.testing.assert_array_equal(h.control_face_of(k), control)
        np.testing.assert_array_equal(h.base_face_of(k), composed)
        keep = ~levels[k].face_hole
        cheap = FaceMap(mesh, k, scheme, boundary)
        shared = FaceMap(mesh, k, scheme, boundary, hierarchy=h)
        for fmap in (cheap, shared):
            np.testing.assert_array_equal(fmap.keep, keep)
            np.testing.assert_array_equal(fmap.parent, control[keep])
    counts, _ = r.topology()
    FaceMap(mesh, 2, scheme, boundary, hierarchy=h).check(counts)


@pytest.mark.parametrize("name,scheme", [("polygons", "catmull-clark"), ("polygons", "loop"), ("cube", "loop"),
                                         ("tri_grid3x3", "catmull-clark")])
def test_recorded_steps_follow_the_closed_form_rule(name, scheme):
    """The step records the hierarchy takes from each level equal those the closed-form rule derives from the
    control mesh's faces alone, and their child counts are the refined levels' counts."""
    mesh = mesh_of(name)
    options = Options(scheme=scheme)
    h = Hierarchy(mesh, 3, options)
    cheap = Parentage.of_mesh(mesh, 3, scheme)
    levels = brute_levels(mesh, 3, options)
    fields = ("scheme", "num_vertices", "num_faces", "num_edges", "num_corners", "face_size")
    for k in (1, 2, 3):
        a, b = h.refinement(k), cheap.refinement(k)
        assert [getattr(a, f) for f in fields] == [getattr(b, f) for f in fields]
        assert (a.face_offsets is None) == (b.face_offsets is None)
        if a.face_offsets is not None:
            np.testing.assert_array_equal(a.face_offsets, b.face_offsets)
        child = levels[k]
        assert (a.child_vertices, a.child_faces, a.child_edges, a.child_corners) == (
            child.num_vertices, child.num_faces, child.num_edges, child.num_corners)
    np.testing.assert_array_equal(h.parentage.base_face_hole, cheap.base_face_hole)


def test_parentage_stores_rules_not_refined_arrays():
    """Only the control level's polygon step keeps an array (its face offsets, of control size); later steps
    keep counts alone, so the parentage of a deep hierarchy costs no refined-size memory."""
    mesh = polygons()
    h = Hierarchy(mesh, 4, Options())
    steps = h.parentage.steps
    assert steps[0].face_offsets is not None and len(steps[0].face_offsets) == mesh.num_faces + 1
    assert all(s.face_offsets is None for s in steps[1:])
    stored = sum(a.nbytes for a in (h.parentage.base_face_hole, h.parentage.control_face, steps[0].face_offsets)
                 if a is not None)
    assert stored <= 16 * (mesh.num_faces + 1)
    assert h.parentage.num_faces(4) == h.final.num_faces


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_face_map_keeps_faces_on_boundaries_tagged_sharp_under_boundary_none(scheme):
    """Boundary "none" leaves out faces at untagged boundaries only (OpenSubdiv's VTX_BOUNDARY_NONE keeps a
    boundary tagged infinitely sharp): the face map reads the same holes as the refiner and agrees with it."""
    mesh = load_mesh("grid3x3" if scheme == "catmull-clark" else "tri_grid3x3")
    edge_faces = np.bincount(mesh.edges.corner_edge, minlength=mesh.num_edges)
    boundary_edges = mesh.edges.edge_verts[edge_faces == 1]
    tagged = ws.Mesh(mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices,
                     creases=boundary_edges[: len(boundary_edges) // 2], crease_sharpness=10.0)
    r = ws.Refiner(tagged, 1, scheme=scheme, boundary="none", device="cpu")
    counts, _ = r.topology()
    fmap = FaceMap(tagged, 1, scheme, "none")
    fmap.check(counts)
    assert 0 < fmap.num_faces < 4 * tagged.num_faces


def test_refinement_rules_of_a_single_step():
    """A Catmull-Clark step over a quad level: child face c of parent c // 4 at corner c % 4, rotated by its
    corner; vertices [V | F | E]; edges [C interior | 2E halves]."""
    step = Refinement("catmull-clark", num_vertices=8, num_faces=6, num_edges=12, num_corners=24, face_size=4)
    face, slot = step.face_parent()
    np.testing.assert_array_equal(face, np.arange(24) // 4)
    np.testing.assert_array_equal(step.face_rotation(), np.arange(24) % 4)
    assert step.vertex_ranges() == ((VERTEX, 0, 8), (FACE, 8, 6), (EDGE, 14, 12))
    kind, index, side = step.edge_parent()
    assert np.all(kind[:24] == FACE) and np.array_equal(index[:24], np.arange(24) // 4)
    assert np.all(kind[24:] == EDGE) and np.array_equal(index[24:], np.arange(24) // 2)
    assert step.next().num_vertices == 26 and step.next().num_faces == 24
    with pytest.raises(ValueError, match="level must be in"):
        Parentage([step], np.zeros(6, bool)).refinement(2)


@pytest.mark.parametrize("rules", ["opensubdiv", "piecewise-smooth"])
@pytest.mark.parametrize("name,scheme", [("cube", "catmull-clark"), ("polygons", "catmull-clark"),
                                         ("icosahedron", "loop"), ("polygons", "loop")])
def test_a_reused_level_0_analysis_changes_nothing(name, scheme, rules, monkeypatch):
    """A hierarchy built from a level-0 hierarchy of the same mesh and options (``reuse``: what the USD bake
    does with the plan's analysis) does not analyse the control mesh again, and its tables, last level and
    refined points are bitwise those of a hierarchy built from scratch."""
    from warp_subdiv.tables import hierarchy as hmod

    mesh = mesh_of(name)
    options = Options(scheme=scheme, rules=rules)
    fresh = Hierarchy(mesh, 2, options)
    calls = []
    real = hmod.base_level
    monkeypatch.setattr(hmod, "base_level", lambda *a, **k: calls.append(1) or real(*a, **k))
    control = Hierarchy(mesh, 0, options)
    assert len(calls) == 1
    reused = Hierarchy(mesh, 2, options, reuse=control)
    assert len(calls) == 1  # level 0 taken from the reused analysis
    np.testing.assert_array_equal(reused.topology()[1], fresh.topology()[1])
    a = ws.Refiner(mesh, 2, options=options, device="cpu")
    b = ws.Refiner(mesh, 2, options=options, device="cpu", reuse=control)
    assert len(calls) == 2  # the Refiner built from scratch analysed; the one reusing the analysis did not
    np.testing.assert_array_equal(a.evaluate(mesh.points), b.evaluate(mesh.points))
    np.testing.assert_array_equal(a.limit_normals(a.evaluate(mesh.points)), b.limit_normals(b.evaluate(mesh.points)))
    del calls[2:]  # (limits read one level deeper may build deeper refiners, which analyse anew)
    other = Options(scheme=scheme, rules="opensubdiv" if rules != "opensubdiv" else "piecewise-smooth")
    assert not control.fits(mesh, other)
    Hierarchy(mesh, 2, other, reuse=control)
    assert len(calls) == 3  # other options: analysed anew
    same = Hierarchy(mesh, 2, options, reuse=reused)
    assert len(calls) == 3 and same.steps is reused.steps  # the same levels: its tables as they are


def test_the_usd_bake_analyses_each_control_mesh_once(tmp_path, monkeypatch):
    """The bake's refiner of a mesh starts from the analysis its plan made for the memory estimate: the
    control mesh is analysed once per mesh, not once for the estimate and again for the refinement."""
    import os

    from warp_subdiv.tables import hierarchy as hmod
    from warp_subdiv.usd import refine_usd

    calls = []
    real = hmod.base_level
    monkeypatch.setattr(hmod, "base_level", lambda *a, **k: calls.append(1) or real(*a, **k))
    scenes = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes")
    result = refine_usd(os.path.join(scenes, "complex_corner.usda"), str(tmp_path / "out.usda"), 2, device="cpu")
    assert len(result.reports) >= 1
    assert len(calls) == len(result.reports), [r.path for r in result.reports]
