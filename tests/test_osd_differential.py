"""Differential tests: rules="opensubdiv" against OpenSubdiv itself.

The oracle is peers/osd/osd_peer.cpp, a small program built against the system's OpenSubdiv (Debian
``libosd-dev``, 3.5; ``peers/install_osd.sh`` installs it) and driven through ``peers/osd_peer.py``. The whole
module skips when the peer cannot be built or run. The peer is first checked against the stored OpenSubdiv
3.6 references (tests/data/*.npz); then our library is compared with it in float64, to 1e-6 of the
coordinates' magnitude (unit normals to 1e-5), at levels 1 to 3, in OpenSubdiv's vertex and face order, on
every basic mesh (tests/data/meshes: both schemes, three boundary modes, both triangle subdivisions), the ten
OpenSubdiv regression shapes (tests/data/opensubdiv-shapes, with their tags and options) and a few hundred
seeded random meshes (infinitely sharp and semi-sharp creases and corners, holes, uniform and Chaikin
creasing, smooth triangles); limit points and T1 x T2 normals at level 2 (random meshes: at their level).
Section 6 feeds both degenerate and non-manifold input: faces that repeat a vertex (adjacent or not),
doubled faces, fins and random non-manifold triangle and polygon soups.
Known disagreements are strict xfails in section 5 whose reasons say exactly what differs, so that they flip
when fixed (one remains: normals at vertices with several sectors, where warp-subdiv averages the sectors'
normals); section 5 also pins cases that once differed.

The peer's input is parsed from the OBJ files here, independently of warp_subdiv.io.obj. Loop with polygons:
the peer gets the fan triangulation warp-subdiv documents, (v0, vi, vi+1) per polygon in face order.
"""
import glob
import os
import sys
import warnings
from functools import lru_cache

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.append(ROOT)  # appended: an installed warp_subdiv keeps precedence over the checkout

from bench.fuzz import box_quads, grid_quads  # noqa: E402
from peers import osd_peer  # noqa: E402

if not osd_peer.available():
    pytest.skip("OpenSubdiv peer unavailable (needs libosd-dev and g++: peers/install_osd.sh) "
                + osd_peer.build_log()[-300:], allow_module_level=True)

import warp_subdiv as ws  # noqa: E402
from conftest import DATA, MESHES, fin_mesh  # noqa: E402
from warp_subdiv.io.obj import read_obj  # noqa: E402

SHAPES = os.path.join(DATA, "opensubdiv-shapes")
RTOL = 1e-6      # of the largest coordinate magnitude
NORMAL_TOL = 1e-5
SCHEME = {"catmull-clark": "catmark", "loop": "loop"}
BOUNDARIES = ("edge-and-corner", "edge-only", "none")
LEVELS = (1, 2, 3)
LIMIT_LEVEL = 2

# ------------------------------------------------------------------------------------ known disagreements
MULTI_SECTOR_NORMAL = (
    "limit normal at a vertex with several sectors (an interior crease or corner): OpenSubdiv's T1 x T2 is one "
    "sector's (its tangents follow the leading crease edge and the faces after it), warp_subdiv's is the "
    "normalised sum of the sectors' normals (as its README documents)")
SEMI_SHARP_BOUNDARY_NONE = (
    "boundary='none' with semi-sharp tags on boundary edges: OpenSubdiv keeps a face at the boundary only "
    "where every boundary edge at its boundary vertices is tagged infinitely sharp; warp_subdiv counts "
    "semi-sharp tags too and keeps more faces")


# ------------------------------------------------------------------------------------------- mesh input
def parse_obj(path: str) -> dict:
    """The OBJ (and .creases/.corners side files) as peer keywords, parsed here, not with warp_subdiv.io.obj.

    Keys: points, counts, indices, creases, crease_sharpness, corners, corner_sharpness, holes, and the tag
    options boundary (None when not tagged) and creasing."""
    pts, counts, idx = [], [], []
    creases, csharp, corners, vsharp, holes = [], [], [], [], []
    boundary, creasing = None, "uniform"
    with open(path, encoding="utf-8") as fh:
        for raw in fh:
            parts = raw.split("#", 1)[0].split()
            if not parts:
                continue
            if parts[0] == "v":
                pts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                ids = [int(t.split("/")[0]) for t in parts[1:]]
                idx.extend(i - 1 if i > 0 else len(pts) + i for i in ids)
                counts.append(len(ids))
            elif parts[0] == "t":
                nint, nfloat, _ = (int(x) for x in parts[2].split("/"))
                ints = [int(x) for x in parts[3:3 + nint]]
                floats = [float(x) for x in parts[3 + nint:3 + nint + nfloat]]
                strings = parts[3 + nint + nfloat:]
                if parts[1] == "crease":  # a chain of edges, one sharpness
                    for a, b in zip(ints[:-1], ints[1:]):
                        creases.append((a, b))
                        csharp.append(floats[0])
                elif parts[1] == "corner":
                    corners.extend(ints)
                    vsharp.extend([floats[0]] * len(ints))
                elif parts[1] == "hole":
                    holes.extend(ints)
                elif parts[1] == "interpolateboundary":
                    boundary = {0: "none", 1: "edge-and-corner", 2: "edge-only"}[ints[0]]
                elif parts[1] == "creasemethod":
                    creasing = strings[0]
    stem = os.path.splitext(path)[0]
    if os.path.exists(stem + ".creases"):
        for row in np.loadtxt(stem + ".creases", ndmin=2):
            creases.append((int(row[0]), int(row[1])))
            csharp.append(float(row[2]))
    if os.path.exists(stem + ".corners"):
        for row in np.loadtxt(stem + ".corners", ndmin=2):
            corners.append(int(row[0]))
            vsharp.append(float(row[1]))
    return dict(points=np.array(pts, float), counts=np.array(counts), indices=np.array(idx), creases=creases,
                crease_sharpness=csharp, corners=corners, corner_sharpness=vsharp, holes=holes,
                boundary=boundary, creasing=creasing)


def fan_triangulate(counts, indices, holes):
    """warp-subdiv's documented Loop triangulation: (v0, vi, vi+1) per polygon, triangles in face order."""
    tris, parent, start = [], [], 0
    for f, n in enumerate(counts):
        face = indices[start:start + n]
        start += n
        for i in range(1, n - 1):
            tris.append([face[0], face[i], face[i + 1]])
            parent.append(f)
    parent = np.array(parent)
    return np.full(len(tris), 3), np.array(tris).reshape(-1), np.flatnonzero(np.isin(parent, holes))


def peer_request(src: dict, level: int, scheme: str, boundary: str, limit: bool = False,
                 triangle_sub: str = "catmark"):
    counts, indices, holes = src["counts"], src["indices"], src["holes"]
    if scheme == "loop" and np.any(np.asarray(counts) != 3):
        counts, indices, holes = fan_triangulate(counts, indices, holes)
    return osd_peer.request(
        src["points"], counts, indices, level, scheme=SCHEME[scheme], boundary=boundary, creasing=src["creasing"],
        triangle_sub=triangle_sub, creases=src["creases"], crease_sharpness=src["crease_sharpness"],
        corners=src["corners"], corner_sharpness=src["corner_sharpness"], holes=holes, limit=limit,
    )


def mesh_of(src: dict) -> "ws.Mesh":
    with_creases = len(src["creases"]) > 0
    return ws.Mesh(src["points"], src["counts"], src["indices"], creases=src["creases"] if with_creases else None,
                   crease_sharpness=src["crease_sharpness"] if with_creases else None, corners=src["corners"],
                   corner_sharpness=src["corner_sharpness"], holes=src["holes"])


def ours(mesh, level, scheme, boundary, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ws.NonManifoldWarning)
        return ws.refine(mesh, level, scheme=scheme, rules="opensubdiv", boundary=boundary, device="cpu",
                         precision="float64", **kw)


class Results(dict):
    """Peer results by case; a short repr, because test reports print the test's arguments."""

    def __repr__(self):
        return f"<{len(self)} OpenSubdiv results>"


# ----------------------------------------------------------------------------------------- comparisons
def assert_points(actual, expected, what=""):
    __tracebackhide__ = True
    assert actual.shape == expected.shape, f"{what}: {actual.shape} vertices vs OpenSubdiv's {expected.shape}"
    scale = max(float(np.abs(expected).max(initial=0.0)), 1e-300)
    err = np.abs(actual - expected).max(axis=1, initial=0.0) if len(expected) else np.zeros(0)
    bad = np.flatnonzero(err > RTOL * scale)
    assert not len(bad), (f"{what}: {len(bad)} of {len(err)} vertices differ, first {bad[0]}: "
                          f"{actual[bad[0]].tolist()} vs OpenSubdiv {expected[bad[0]].tolist()}")


def assert_faces(refined, peer_level, what=""):
    __tracebackhide__ = True
    counts, indices = peer_level.faces()
    np.testing.assert_array_equal(refined.face_vertex_counts, counts, err_msg=f"{what}: face sizes")
    np.testing.assert_array_equal(refined.face_vertex_indices, indices, err_msg=f"{what}: face vertices")


def semi_sharp_vertices(peer):
    """Level-N vertices that had a semi-sharp (0 < s < 10) sharpness or incident edge on any level (vertex v
    of a level is vertex v of the next)."""
    out = np.zeros(len(peer.last.points), bool)
    for lvl in peer.levels:
        semi = (lvl.vertex_sharpness > 0) & (lvl.vertex_sharpness < 10)
        semi_edges = (lvl.edge_sharpness > 0) & (lvl.edge_sharpness < 10)
        semi[lvl.edge_vertices[semi_edges].reshape(-1)] = True
        out[:len(semi)] |= semi
    return out


def assert_normals(actual, expected, mask, what=""):
    __tracebackhide__ = True
    err = np.linalg.norm(actual - expected, axis=1)
    bad = np.flatnonzero(mask & (err > NORMAL_TOL))
    assert not len(bad), (f"{what}: normals of {len(bad)} vertices differ, first {bad[0]}: "
                          f"{actual[bad[0]].tolist()} vs OpenSubdiv {expected[bad[0]].tolist()}")


def defined_normals(peer):
    """Vertices where OpenSubdiv's T1 x T2 is not zero: around a face that repeats a vertex (a quad that is
    geometrically a triangle) the limit tangents can be parallel or vanish, and there the surface has no
    normal to compare (warp_subdiv reports a unit vector, OpenSubdiv a zero one)."""
    cross = np.linalg.norm(np.cross(peer.limit_tan1, peer.limit_tan2), axis=1)
    scale = max(float(np.abs(peer.limit_points).max(initial=0.0)), 1e-300)
    return cross > 1e-12 * scale * scale


def assert_limit(refined, peer, what=""):
    """Limit points everywhere; T1 x T2 normals at one-sector vertices (PeerLevel.single_sector; see
    MULTI_SECTOR_NORMAL), semi-sharp boundary vertices included, but where OpenSubdiv's
    normal is zero (defined_normals)."""
    __tracebackhide__ = True
    assert_points(refined.limit_points(), peer.limit_points, what + " limit points")
    mask = peer.last.single_sector() & defined_normals(peer)
    assert_normals(refined.limit_normals(), peer.limit_normals(), mask, what + " limit normals")


# ============================================================================ 1. the oracle itself
REFERENCES = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(DATA, "*.npz")))


def reference_peer(case):
    name, scheme, boundary, level = case.split("__")
    src = parse_obj(os.path.join(MESHES, name + ".obj"))
    scheme = {"catmark": "catmull-clark", "loop": "loop"}[scheme]
    return osd_peer.refine_many([peer_request(src, int(level[1:]), scheme, boundary.replace("_", "-"),
                                              limit=True)])[0]


def test_peer_reproduces_the_stored_opensubdiv_36_cube():
    """The wrapper's peer output on the reference case equals OpenSubdiv 3.6's stored L2 points."""
    ref = np.load(os.path.join(DATA, "cube__catmark__edge_and_corner__L2.npz"))
    src = parse_obj(os.path.join(MESHES, "cube.obj"))
    out = osd_peer.refine(src["points"], src["counts"], src["indices"], 2, scheme="catmark",
                          boundary="edge-and-corner")
    np.testing.assert_allclose(out.levels[2].points, ref["L2_points"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("case", REFERENCES)
def test_peer_matches_every_stored_reference(case):
    """Every stored OpenSubdiv 3.6 reference: points, faces, rules, sharpness, limit positions and tangents."""
    ref = np.load(os.path.join(DATA, case + ".npz"))
    out = reference_peer(case)
    top = len(out.levels) - 1
    for lvl in range(top + 1):
        got = out.levels[lvl]
        np.testing.assert_allclose(got.points, ref[f"L{lvl}_points"], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.face_counts, ref[f"L{lvl}_face_counts"])
        np.testing.assert_array_equal(got.face_indices, ref[f"L{lvl}_face_indices"])
        np.testing.assert_array_equal(got.face_holes, ref[f"L{lvl}_face_is_hole"])
        np.testing.assert_array_equal(got.vertex_rules, ref[f"L{lvl}_vertex_rule"])
        np.testing.assert_array_equal(got.vertex_sharpness, ref[f"L{lvl}_vertex_sharpness"])
        np.testing.assert_array_equal(got.edge_vertices.reshape(-1), ref[f"L{lvl}_edge_vertices"])
        np.testing.assert_array_equal(got.edge_sharpness, ref[f"L{lvl}_edge_sharpness"])
    for mine, theirs in (("limit_points", "limit_points"), ("limit_tan1", "limit_tangent1"),
                         ("limit_tan2", "limit_tangent2")):
        np.testing.assert_allclose(getattr(out, mine), ref[theirs], rtol=0, atol=1e-12)


def test_peer_face_varying_follows_vertex_interpolation_when_the_topologies_agree():
    """A face-varying channel holding the positions, indexed like the vertices, with smooth face-varying
    interpolation, refines exactly as the vertex data under edge-only boundaries (a check of the peer's
    face-varying path, ready for when warp_subdiv refines face-varying data)."""
    src = parse_obj(os.path.join(MESHES, "grid3x3.obj"))
    out = osd_peer.refine(src["points"], src["counts"], src["indices"], 3, boundary="edge-only",
                          fvar_linear="none", fvar=(src["points"], src["indices"]))
    for lvl in out.levels:
        np.testing.assert_allclose(lvl.fvar_values[lvl.fvar_indices], lvl.points[lvl.face_indices],
                                   rtol=0, atol=1e-12)


def test_peer_refuses_what_opensubdiv_refuses():
    src = parse_obj(os.path.join(MESHES, "cube.obj"))
    with pytest.raises(osd_peer.PeerError, match="non-triangular faces not supported by Loop"):
        osd_peer.refine(src["points"], src["counts"], src["indices"], 1, scheme="loop")


# ============================================================================ 2. basic meshes
BASIC = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(MESHES, "*.obj")))
_BASIC_SRC = {name: parse_obj(os.path.join(MESHES, name + ".obj")) for name in BASIC}
# (mesh, scheme, boundary, Catmull-Clark triangle subdivision): "smooth" where a mesh has triangles
BASIC_CASES = [(n, s, b, t) for n in BASIC for s in SCHEME for b in BOUNDARIES for t in ("catmark", "smooth")
               if t == "catmark" or (s == "catmull-clark" and np.any(_BASIC_SRC[n]["counts"] == 3))]


def case_id(name, scheme, boundary, tri_sub):
    return f"{name}-{scheme}-{boundary}" + ("-smooth_triangles" if tri_sub == "smooth" else "")


@pytest.fixture(scope="module")
def basic_peer():
    """OpenSubdiv's refinement of every basic case to level 3, and to LIMIT_LEVEL with limits, in one run."""
    keys = [c + (limit,) for c in BASIC_CASES for limit in (False, True)]
    reqs = [peer_request(_BASIC_SRC[n], LIMIT_LEVEL if limit else max(LEVELS), s, b, limit=limit, triangle_sub=t)
            for n, s, b, t, limit in keys]
    return Results(zip(keys, osd_peer.refine_many(reqs)))


@lru_cache(maxsize=None)
def basic_ours(name, scheme, boundary, tri_sub, level):
    return ours(read_obj(os.path.join(MESHES, name + ".obj")).mesh, level, scheme, boundary,
                triangle_subdivision=tri_sub)


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("name,scheme,boundary,tri_sub", [pytest.param(*c, id=case_id(*c)) for c in BASIC_CASES])
def test_basic_mesh(basic_peer, name, scheme, boundary, tri_sub, level):
    """Points and faces in OpenSubdiv's order, hole faces (and with boundary='none' the faces at the
    boundary) left out."""
    expected = basic_peer[name, scheme, boundary, tri_sub, False].levels[level]
    out = basic_ours(name, scheme, boundary, tri_sub, level)
    assert_points(out.points, expected.points, f"L{level}")
    assert_faces(out, expected, f"L{level}")


@pytest.mark.parametrize("name,scheme,boundary,tri_sub", [pytest.param(*c, id=case_id(*c)) for c in BASIC_CASES])
def test_basic_mesh_limit(basic_peer, name, scheme, boundary, tri_sub):
    assert_limit(basic_ours(name, scheme, boundary, tri_sub, LIMIT_LEVEL),
                 basic_peer[name, scheme, boundary, tri_sub, True], f"L{LIMIT_LEVEL}")


# ============================================================================ 3. OpenSubdiv's shapes
SHAPE_NAMES = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(SHAPES, "*.obj")))
_SHAPE_SRC = {name: parse_obj(os.path.join(SHAPES, name + ".obj")) for name in SHAPE_NAMES}


def shape_options(name):
    src = _SHAPE_SRC[name]
    return ("loop" if name.startswith("loop") else "catmull-clark"), src["boundary"] or "edge-only"


@pytest.fixture(scope="module")
def shapes_peer():
    keys = [(n, limit) for n in SHAPE_NAMES for limit in (False, True)]
    reqs = [peer_request(_SHAPE_SRC[n], LIMIT_LEVEL if limit else max(LEVELS), *shape_options(n), limit=limit)
            for n, limit in keys]
    return Results(zip(keys, osd_peer.refine_many(reqs)))


@lru_cache(maxsize=None)
def shape_ours(name, level):
    scheme, boundary = shape_options(name)
    data = read_obj(os.path.join(SHAPES, name + ".obj"))  # warp_subdiv's own reading of the tags
    assert data.options.get("boundary", "edge-only") == boundary
    assert data.options.get("crease_method", "uniform") == _SHAPE_SRC[name]["creasing"]
    return ours(data.mesh, level, scheme, boundary, crease_method=_SHAPE_SRC[name]["creasing"])


@pytest.mark.parametrize("name", SHAPE_NAMES)
def test_shape(shapes_peer, name):
    """Points and faces at levels 1 to 3 with the shape's tags and options (no interpolateboundary tag:
    edge-only), limit points and normals at level 2."""
    for level in LEVELS:
        expected = shapes_peer[name, False].levels[level]
        out = shape_ours(name, level)
        assert_points(out.points, expected.points, f"{name} L{level}")
        assert_faces(out, expected, f"{name} L{level}")
    assert_limit(shape_ours(name, LIMIT_LEVEL), shapes_peer[name, True], name)


# ============================================================================ 4. random meshes
NUM_RANDOM = 300


def _grid(rng, nx, ny):
    pts, quads = grid_quads(nx, ny)
    pts[:, 2] = 0.3 * rng.standard_normal(len(pts))
    pts[:, :2] += 0.15 * rng.standard_normal((len(pts), 2))
    return pts, quads


def _box(rng, n):
    """The surface of a cube cut into n x n quads per side, facing outward, jittered."""
    pts, quads = box_quads(n)
    pts = pts / n - 0.5
    return pts + 0.08 * rng.standard_normal(pts.shape) / n, quads


def _split(rng, quads):
    tris = []
    for a, b, c, d in quads:
        tris += [[a, b, c], [a, c, d]] if rng.random() < 0.5 else [[a, b, d], [b, c, d]]
    return tris


def random_case(seed):
    """A seeded random mesh: (source dict, scheme, boundary, level, triangle subdivision).

    seed % 5 picks quads (Catmull-Clark), triangles (Loop) or triangles under Catmull-Clark, on an open grid
    or a closed box; (seed // 5) % 4 infinitely sharp tags, or semi-sharp ones (sharpness in multiples of
    1/16, exact in OpenSubdiv's float32) with uniform or Chaikin creasing; (seed // 20) % 3 the boundary mode;
    1 + (seed // 60) % 3 the level."""
    rng = np.random.default_rng(seed)
    kind, flavour = seed % 5, (seed // 5) % 4
    if kind in (0, 1) or (kind == 4 and rng.random() < 0.5):
        pts, faces = _grid(rng, int(rng.integers(1, 5)), int(rng.integers(1, 5)))
    else:
        pts, faces = _box(rng, int(rng.integers(1, 4)))
    scheme, tri_sub = "catmull-clark", "catmark"
    if kind in (1, 3, 4):
        faces = _split(rng, faces)
        scheme = "loop" if kind in (1, 3) else "catmull-clark"
        tri_sub = ("catmark", "smooth")[int(rng.integers(2))] if kind == 4 else "catmark"
    counts = np.array([len(f) for f in faces])
    indices = np.array(faces).reshape(-1)
    nxt = np.concatenate([f[1:] + f[:1] for f in faces])
    edges, count = np.unique(np.sort(np.stack([indices, nxt], axis=1), axis=1), axis=0, return_counts=True)
    tagged = rng.random(len(edges)) < 0.2  # boundary edges too: their tags matter to boundary="none"
    creases, on_boundary = edges[tagged], count[tagged] == 1
    corners = np.flatnonzero(rng.random(len(pts)) < 0.08)
    if flavour >= 2:  # semi-sharp; boundary edges infinitely sharp (semi-sharp ones: SEMI_SHARP_BOUNDARY_NONE)
        crease_sharpness = np.where(on_boundary, 10.0, rng.integers(4, 65, len(creases)) / 16.0)
        corner_sharpness = rng.integers(4, 65, len(corners)) / 16.0
    else:
        crease_sharpness, corner_sharpness = np.full(len(creases), 10.0), np.full(len(corners), 10.0)
    holes = np.flatnonzero(rng.random(len(faces)) < 0.1)
    if len(holes) == len(faces):
        holes = holes[1:]
    src = dict(points=pts, counts=counts, indices=indices, creases=creases, crease_sharpness=crease_sharpness,
               corners=corners, corner_sharpness=corner_sharpness, holes=holes, boundary=None,
               creasing="chaikin" if flavour == 3 else "uniform")
    return src, scheme, BOUNDARIES[(seed // 20) % 3], 1 + (seed // 60) % 3, tri_sub


@pytest.fixture(scope="module")
def random_peer():
    reqs = []
    for seed in range(NUM_RANDOM):
        src, scheme, boundary, level, tri_sub = random_case(seed)
        reqs.append(peer_request(src, level, scheme, boundary, limit=True, triangle_sub=tri_sub))
    return Results(enumerate(osd_peer.refine_many(reqs)))


@pytest.mark.parametrize("seed", range(NUM_RANDOM))
def test_random_mesh(random_peer, seed):
    """Points, faces, limit points and normals of a random mesh (see random_case)."""
    src, scheme, boundary, level, tri_sub = random_case(seed)
    peer = random_peer[seed]
    out = ours(mesh_of(src), level, scheme, boundary, crease_method=src["creasing"], triangle_subdivision=tri_sub)
    what = f"seed {seed}: {scheme} {boundary} L{level} {src['creasing']} creasing, {tri_sub} triangles"
    assert_points(out.points, peer.last.points, what)
    assert_faces(out, peer.last, what)
    assert_limit(out, peer, what)


# ============================================================================ 5. behaviours and disagreements
def test_boundary_none_is_edge_only_with_boundary_faces_as_holes():
    """What OpenSubdiv does with VTX_BOUNDARY_NONE (and warp_subdiv too): every vertex is refined as under
    EDGE_ONLY (boundary edges sharp, one-face corners follow the crease rule) and every face touching a
    boundary vertex with an untagged boundary edge is a hole face, kept in the vertex numbering but not
    output."""
    src = parse_obj(os.path.join(MESHES, "tri_grid3x3.obj"))
    none, edge = osd_peer.refine_many([peer_request(src, 2, "loop", b) for b in ("none", "edge-only")])
    for a, b in zip(none.levels, edge.levels):
        np.testing.assert_array_equal(a.points, b.points)
    assert np.flatnonzero(none.levels[0].face_holes).tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 10, 11, 12, 13, 14,
                                                                  15, 16, 17]
    out = ours(mesh_of(src), 2, "loop", "none")
    assert_points(out.points, none.levels[2].points)
    assert_faces(out, none.levels[2])


def test_boundary_none_keeps_faces_whose_boundary_edges_are_all_tagged():
    src = parse_obj(os.path.join(MESHES, "grid3x3.obj"))
    # the boundary edges at vertices 0, 1 and 4, all tagged: face 0 touches no untagged boundary edge
    src["creases"], src["crease_sharpness"] = [(0, 1), (1, 2), (0, 4), (4, 8)], [10.0] * 4
    peer = osd_peer.refine_many([peer_request(src, 1, "catmull-clark", "none")])[0]
    assert np.flatnonzero(peer.levels[0].face_holes).tolist() == [1, 2, 3, 5, 6, 7, 8]
    assert_faces(ours(mesh_of(src), 1, "catmull-clark", "none"), peer.levels[1], "L1")


@pytest.mark.parametrize("sharpness", [5.0, 0.5])
def test_boundary_none_with_semi_sharp_boundary_tags(sharpness):
    src = parse_obj(os.path.join(MESHES, "grid3x3.obj"))
    src["creases"], src["crease_sharpness"] = [(0, 1), (1, 2), (0, 4), (4, 8)], [sharpness] * 4
    peer = osd_peer.refine_many([peer_request(src, 1, "catmull-clark", "none")])[0]
    assert np.flatnonzero(peer.levels[0].face_holes).tolist() == [0, 1, 2, 3, 5, 6, 7, 8]
    assert_faces(ours(mesh_of(src), 1, "catmull-clark", "none"), peer.levels[1], "L1")


@pytest.mark.parametrize("name", ["catmark_cube_creases1", "loop_triangle_edgeonly"])
def test_limit_points_at_semi_sharp_vertices(shapes_peer, name):
    """PrimvarRefiner::Limit applies the mask of each vertex's rule on the last level, also where semi-sharp
    features remain or have just decayed."""
    peer = shapes_peer[name, True]
    semi = semi_sharp_vertices(peer)
    assert semi.any()
    got = shape_ours(name, LIMIT_LEVEL).limit_points()
    assert_points(got[semi], peer.limit_points[semi], name)


def test_loop_limit_normal_at_a_boundary_vertex_with_four_faces():
    """OpenSubdiv's Loop cross tangent at crease vertices with four or more faces (its general formula)."""
    src = parse_obj(os.path.join(MESHES, "tri_halffan.obj"))  # vertex 0: four faces on a straight boundary
    peer = osd_peer.refine_many([peer_request(src, 1, "loop", "edge-only", limit=True)])[0]
    out = ours(mesh_of(src), 1, "loop", "edge-only")
    np.testing.assert_allclose(out.limit_normals()[0], peer.limit_normals()[0], atol=NORMAL_TOL)


def test_limit_normal_at_a_reflex_boundary_corner_of_a_flat_mesh():
    # two quads in the plane z = 0 (counter-clockwise seen from +z); vertex 1, the middle of the bottom
    # boundary, is tagged a corner and pushed into the faces' side, so their angle there exceeds 180 degrees
    points = np.array([[0, 0, 0], [1, 0.2, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], float)
    counts, indices = [4, 4], [0, 1, 4, 3, 1, 2, 5, 4]
    peer = osd_peer.refine(points, counts, indices, 1, boundary="edge-only", corners=[1], limit=True)
    np.testing.assert_allclose(peer.limit_normals()[1], [0, 0, 1], atol=1e-12)
    out = ours(ws.Mesh(points, counts, indices, corners=[1]), 1, "catmull-clark", "edge-only")
    np.testing.assert_allclose(out.limit_normals()[1], [0, 0, 1], atol=NORMAL_TOL)


@pytest.mark.xfail(strict=True, reason=MULTI_SECTOR_NORMAL)
def test_limit_normals_at_multi_sector_vertices():
    src = parse_obj(os.path.join(MESHES, "cube_creased.obj"))
    peer = osd_peer.refine_many([peer_request(src, 1, "catmull-clark", "edge-and-corner", limit=True)])[0]
    multi = ~peer.last.single_sector()
    assert multi[:8].all()  # the eight corners, three sectors each
    out = ours(mesh_of(src), 1, "catmull-clark", "edge-and-corner")
    assert_normals(out.limit_normals(), peer.limit_normals(), multi, "multi-sector")


@pytest.mark.parametrize("tags", [dict(corners=[1], corner_sharpness=[0.5]),
                                  dict(creases=[[1, 4]], crease_sharpness=[0.5])], ids=["corner", "crease"])
def test_limit_normal_at_a_semi_sharp_boundary_vertex(tags):
    # 2 x 2 quads; vertex 1, the middle of the bottom boundary, gets a semi-sharp corner or interior crease
    points = np.array([[0, 0, 1], [1, 0, 0], [2, 0, 1], [0, 1, 0], [1, 1, 1], [2, 1, 0], [0, 2, 0], [1, 2, 0],
                       [2, 2, 0]], float)
    counts, indices = [4] * 4, [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6, 4, 5, 8, 7]
    peer = osd_peer.refine(points, counts, indices, 1, boundary="edge-only", limit=True, **tags)
    np.testing.assert_allclose(peer.limit_normals()[1], [0, -1 / np.sqrt(5), 2 / np.sqrt(5)], atol=1e-12)
    out = ours(ws.Mesh(points, counts, indices, **tags), 1, "catmull-clark", "edge-only")
    np.testing.assert_allclose(out.limit_normals()[1], peer.limit_normals()[1], atol=NORMAL_TOL)


def test_non_manifold_fin_is_a_crease():
    """Three sheets of two quads meeting along a spine a-b-c: b (two non-manifold edges, six faces, five
    edges) follows the crease rule in both, a and c are corners."""
    fin = fin_mesh()
    points, counts, indices = fin.points, fin.face_vertex_counts, fin.face_vertex_indices
    peer = osd_peer.refine(points, counts, indices, 2, boundary="edge-only")
    assert peer.levels[0].vertex_rules[:3].tolist() == [osd_peer.RULE_CORNER, osd_peer.RULE_CREASE,
                                                        osd_peer.RULE_CORNER]
    for level in (1, 2):
        out = ours(ws.Mesh(points, counts, indices), level, "catmull-clark", "edge-only")
        assert_points(out.points, peer.levels[level].points, f"L{level}")
        assert_faces(out, peer.levels[level], f"L{level}")


def test_non_manifold_vertex_of_two_sharp_edges_is_a_corner():
    points = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0.5], [2, 1, 0], [0, 2, 0], [1, 2, 0],
                       [2, 2, 0]], float)
    counts, indices = [4] * 4, [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6, 4, 7, 8, 5]  # the last face reversed
    peer = osd_peer.refine(points, counts, indices, 1, boundary="edge-only")
    assert peer.levels[0].vertex_rules[4] == osd_peer.RULE_CORNER  # two non-manifold edges (4, 5), (4, 7)
    out = ours(ws.Mesh(points, counts, indices), 1, "catmull-clark", "edge-only")
    assert_points(out.points, peer.levels[1].points, "L1")


# ============================================================================ 6. degenerate and non-manifold input
NUM_NONMANIFOLD = 300


def nonmanifold_case(seed):
    """A seeded degenerate or non-manifold mesh that OpenSubdiv refines: (source dict, scheme, boundary, level,
    triangle subdivision).

    seed % 4 picks a soup of random faces over a few vertices (faces that repeat a vertex, adjacent or not;
    doubled faces; edges of three or more faces; vertices joining several fans; unused vertices), a soup of
    faces of distinct vertices, or a grid or box with some faces collapsed (a vertex repeated), doubled,
    flipped or dropped and some vertices merged; (seed // 4) % 2 Loop (triangles) or Catmull-Clark (polygons);
    about half get random crease tags (infinitely sharp or semi-sharp, on edges and on degenerate pairs),
    corners and holes; the boundary mode, creasing, triangle subdivision and level 1-3 vary with the seed."""
    rng = np.random.default_rng(10_000 + seed)
    kind, loop = seed % 4, (seed // 4) % 2 == 1
    size = (lambda: 3) if loop else (lambda: int(rng.integers(3, 7)))
    if kind == 0:
        nv = int(rng.integers(3, 14))
        faces = [rng.integers(0, nv, size()) for _ in range(int(rng.integers(1, 14)))]
        pts = rng.standard_normal((nv, 3))
    elif kind == 1:
        nv = int(rng.integers(6, 18))
        faces = [rng.choice(nv, size(), replace=False) for _ in range(int(rng.integers(2, 16)))]
        pts = rng.standard_normal((nv, 3))
    else:
        pts, quads = _grid(rng, int(rng.integers(1, 4)), int(rng.integers(1, 4))) if kind == 2 else _box(rng, 1)
        faces = [np.array(f) for f in (_split(rng, quads) if loop else quads)]
        out = []
        for f in faces:
            r = rng.random()
            if r < 0.15:
                f = f.copy()
                f[int(rng.integers(len(f)))] = f[int(rng.integers(len(f)))]
            elif r < 0.25:
                out.append(f.copy())
            elif r < 0.3:
                f = f[::-1].copy()
            elif r < 0.33:
                continue
            out.append(f)
        faces = out or faces[:1]
        if rng.random() < 0.3:
            a, b = rng.integers(0, len(pts), 2)
            faces = [np.where(f == a, b, f) for f in faces]
    counts = np.array([len(f) for f in faces])
    indices = np.concatenate(faces)
    creases, crease_sharpness, corners, corner_sharpness, holes = [], [], [], [], []
    if rng.random() < 0.5:
        h = rng.integers(0, len(indices), int(rng.integers(1, 5)))
        nxt = np.concatenate([np.roll(f, -1) for f in faces])
        creases = np.stack([indices[h], nxt[h]], axis=1)
        crease_sharpness = rng.choice([10.0, 10.0, 1.5, 0.5, 2.25], len(creases))
        corners = np.unique(rng.integers(0, len(pts), int(rng.integers(0, 3))))
        corner_sharpness = rng.choice([10.0, 1.0], len(corners))
        holes = np.flatnonzero(rng.random(len(faces)) < 0.1)[: len(faces) - 1]
    src = dict(points=pts, counts=counts, indices=indices, creases=creases, crease_sharpness=crease_sharpness,
               corners=corners, corner_sharpness=corner_sharpness, holes=holes, boundary=None,
               creasing=("uniform", "chaikin")[int(rng.integers(2))])
    tri_sub = "smooth" if (not loop and rng.random() < 0.3) else "catmark"
    return (src, "loop" if loop else "catmull-clark", BOUNDARIES[int(rng.integers(3))], 1 + int(rng.integers(3)),
            tri_sub)


@pytest.fixture(scope="module")
def nonmanifold_peer():
    reqs = []
    for seed in range(NUM_NONMANIFOLD):
        src, scheme, boundary, level, tri_sub = nonmanifold_case(seed)
        reqs.append(peer_request(src, level, scheme, boundary, limit=True, triangle_sub=tri_sub))
    return Results(enumerate(osd_peer.refine_many(reqs)))


@pytest.mark.parametrize("seed", range(NUM_NONMANIFOLD))
def test_nonmanifold_mesh(nonmanifold_peer, seed):
    """Points and faces of every level, limit points and (where defined) normals of a degenerate or
    non-manifold mesh (see nonmanifold_case), as OpenSubdiv refines it."""
    src, scheme, boundary, level, tri_sub = nonmanifold_case(seed)
    peer = nonmanifold_peer[seed]
    mesh = mesh_of(src)
    what = f"seed {seed}: {scheme} {boundary} {src['creasing']} creasing, {tri_sub} triangles"
    for lvl in range(1, level + 1):
        out = ours(mesh, lvl, scheme, boundary, crease_method=src["creasing"], triangle_subdivision=tri_sub)
        assert_points(out.points, peer.levels[lvl].points, f"{what} L{lvl}")
        assert_faces(out, peer.levels[lvl], f"{what} L{lvl}")
    assert_limit(out, peer, what)


@pytest.mark.parametrize("faces", [[[0, 1, 1, 2]], [[0, 1, 0, 2]], [[0, 1, 2], [0, 1, 2]], [[0, 1, 2], [2, 1, 0]],
                                   [[0, 0, 0]], [[0, 1, 2, 3], [3, 2, 2, 4], [0, 3, 4, 4]]],
                         ids=["adjacent-repeat", "repeat", "doubled", "doubled-flipped", "one-vertex",
                              "strip-with-repeats"])
@pytest.mark.parametrize("scheme", list(SCHEME))
def test_small_degenerate_meshes(faces, scheme):
    """Hand-made degenerate faces (a quad that repeats a vertex, next to itself or not; a face doubled, with
    either winding; a triangle of one vertex; a strip of such quads) refine as in OpenSubdiv, levels 1-3."""
    counts = [len(f) for f in faces]
    indices = np.concatenate(faces)
    if scheme == "loop" and any(c != 3 for c in counts):
        counts, indices, _ = fan_triangulate(counts, indices, [])
    points = np.random.default_rng(5).standard_normal((int(indices.max()) + 1, 3))
    peer = osd_peer.refine(points, counts, indices, 3, scheme=SCHEME[scheme], boundary="edge-only")
    for level in (1, 2, 3):
        out = ours(ws.Mesh(points, counts, indices), level, scheme, "edge-only")
        assert_points(out.points, peer.levels[level].points, f"L{level}")
        assert_faces(out, peer.levels[level], f"L{level}")
