"""Face-varying channels whose values are each used by one face corner (UVs authored without indices): the
value mesh's tags in closed form equal the general path's, and so do the refined values, bit for bit."""
import warnings

import numpy as np
import pytest

import warp_subdiv as ws
from test_osd_differential import mesh_of, random_case
from warp_subdiv.options import FaceVaryingMode
from warp_subdiv.tables import facevarying

FVAR_MODES = FaceVaryingMode.values()
BOUNDARIES = ("edge-only", "edge-and-corner", "none")


def _bits(a):
    a = np.ascontiguousarray(a)
    return a.view(np.uint32 if a.dtype == np.float32 else np.uint64)


def polygons_mesh(rng):
    """An open grid of quads with some merged into pentagons and hexagons, some split into triangles, a
    non-manifold fin (a third face on an interior edge), a lone face and a bow-tie vertex (two faces touching
    at one vertex only), with creases, corners and a hole."""
    nx, ny = 5, 4
    x, y = np.meshgrid(np.arange(nx + 1, dtype=float), np.arange(ny + 1, dtype=float))
    pts = [np.stack([x.ravel(), y.ravel(), 0.2 * rng.standard_normal(x.size)], axis=1)]
    v = lambda i, j: j * (nx + 1) + i  # noqa: E731
    faces = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)
            if i == 0 and j % 2 == 0:  # (merged with the next one)
                continue
            if i == 1 and j % 2 == 0:  # the two quads as a hexagon (j 0) or a pentagon (j 2: a T-junction)
                hexagon = [v(0, j), a, b, c, d, v(0, j + 1)]
                faces.append(hexagon if j == 0 else hexagon[:1] + hexagon[2:])
                continue
            kind = rng.integers(3)
            if kind == 0:
                faces += [[a, b, c], [a, c, d]]
            else:
                quad = [a, b, c, d]
                k = int(rng.integers(4))
                faces.append(quad[k:] + quad[:k])
    base = len(pts[0])
    # a fin on the edge (v(2,1), v(3,1)), a lone triangle, and a bow-tie pair touching at vertex base + 4
    pts.append(np.array([[2.5, 1.0, 1.0], [9, 9, 0], [10, 9, 0], [9, 10, 0],
                         [12, 12, 0], [13, 12, 0], [13, 13, 0], [11, 11, 0], [11, 12, 0]]))
    faces.append([v(2, 1), v(3, 1), base])
    faces.append([base + 1, base + 2, base + 3])
    faces.append([base + 4, base + 5, base + 6])
    faces.append([base + 4, base + 7, base + 8])
    counts = np.array([len(f) for f in faces])
    indices = np.concatenate(faces)
    return ws.Mesh(np.concatenate(pts), counts, indices, creases=[[v(1, 1), v(2, 1)], [v(3, 2), v(3, 3)]],
                   crease_sharpness=[10.0, 1.5], corners=[v(4, 2), base + 4], corner_sharpness=[10.0, 2.0],
                   holes=[len(faces) - 5])


def cases():
    """(name, mesh, scheme, boundary, level): random meshes of the differential tests (tags, semi-sharp, holes,
    triangles under both schemes, open and closed) and the polygon mesh above under both schemes."""
    out = []
    for seed in range(0, 60, 3):
        src, scheme, boundary, level, _ = random_case(seed)
        out.append((f"random{seed}", mesh_of(src), scheme, boundary, min(level, 2)))
    for k in range(4):
        mesh = polygons_mesh(np.random.default_rng(k))
        out.append((f"polygons{k}", mesh, ("catmull-clark", "loop")[k % 2], BOUNDARIES[k % 3], 1 + k % 2))
    return out


CASES = cases()


def unshared_indices(n, kind, rng):
    """Value indices used once each: in corner order (unindexed UVs), shuffled, or offset (values left unused)."""
    if kind == "arange":
        return np.arange(n)
    if kind == "shuffled":
        return rng.permutation(n)
    return np.arange(n) + 3


def _tags(mesh, idx, mode, boundary, scheme, general, monkeypatch):
    with monkeypatch.context() as m:
        if general:
            m.setattr(facevarying, "_unshared", lambda idx: False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ws.NonManifoldWarning)
            return facevarying._ValueTags(mesh, idx, mode, boundary, scheme)


@pytest.mark.parametrize("kind", ["arange", "shuffled", "offset"])
@pytest.mark.parametrize("name,mesh,scheme,boundary,level", CASES, ids=[c[0] for c in CASES])
def test_unshared_tags_equal_the_general_path(name, mesh, scheme, boundary, level, kind, monkeypatch):
    """Every mode: the value-mesh vertex of every corner, each one's source value and vertex, their corner
    sharpness and the islands are those of the general path (np.unique of the (vertex, value) pairs, the
    per-value counts of Vtr::FVarLevel's rules)."""
    rng = np.random.default_rng(len(name))
    idx = unshared_indices(len(mesh.face_vertex_indices), kind, rng)
    for mode in FVAR_MODES:
        fast = _tags(mesh, idx, mode, boundary, scheme, False, monkeypatch)
        general = _tags(mesh, idx, mode, boundary, scheme, True, monkeypatch)
        # (Loop refines a polygon's fan triangles, which share its first corner's value: not unshared)
        assert fast.unshared == (scheme != "loop" or mesh.is_all(3)) and not general.unshared
        for attr in ("pid", "source", "pair_vertex", "corner_sharp"):
            np.testing.assert_array_equal(getattr(fast, attr), getattr(general, attr), err_msg=f"{mode} {attr}")
        np.testing.assert_array_equal(fast.islands(), general.islands(), err_msg=str(mode))


def test_shared_or_sparse_indices_take_the_general_path():
    """A value used twice (some UVs shared, some per corner), or a numbering far sparser than the corners:
    not unshared."""
    idx = np.arange(12)
    assert facevarying._unshared(idx)
    shared = idx.copy()
    shared[5] = 4
    assert not facevarying._unshared(shared)
    assert not facevarying._unshared(idx * 100)
    assert not facevarying._unshared(np.zeros(0, dtype=np.int64))


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("name,mesh,scheme,boundary,level", CASES[::3] + CASES[-4:],
                         ids=[c[0] for c in CASES[::3] + CASES[-4:]])
def test_unshared_values_refine_to_the_same_bits(name, mesh, scheme, boundary, level, precision, monkeypatch):
    """Every mode, per-corner values and a mix of shared and per-corner ones: the channel's refined values and
    indices are the general path's, bit for bit (islands refined apart, MIN_ISLANDS 1, so that the small meshes'
    islands take the single-face refiners)."""
    monkeypatch.setattr(facevarying, "MIN_ISLANDS", 1)
    rng = np.random.default_rng(7)
    n = len(mesh.face_vertex_indices)
    own = rng.random(len(mesh.face_vertex_counts)) < 0.5
    mixed = np.where(np.repeat(own, mesh.face_vertex_counts), mesh.num_vertices + np.arange(n),
                     mesh.face_vertex_indices)
    uv = rng.random((mesh.num_vertices + n + 3, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ws.NonManifoldWarning)
        r = ws.Refiner(mesh, level, scheme=scheme, boundary=boundary, device="cpu", precision=precision)
        for idx in (np.arange(n), rng.permutation(n), mixed):
            for mode in FVAR_MODES:
                fast = facevarying.FaceVaryingChannel(r, idx, mode)
                values, at = fast.evaluate(uv)
                with monkeypatch.context() as m:
                    m.setattr(facevarying, "_unshared", lambda idx: False)
                    general = facevarying.FaceVaryingChannel(r, idx, mode)
                expected, expected_at = general.evaluate(uv)
                np.testing.assert_array_equal(_bits(values), _bits(expected), err_msg=str(mode))
                np.testing.assert_array_equal(at, expected_at, err_msg=str(mode))


@pytest.mark.parametrize("n", [3, 4, 5, 6, 7])
def test_vertex_orders_equal_sorting_and_unique(n):
    """Islands' vertex orders (ranks by pairwise comparison, groups by a count per key, up to SMALL_FACE
    corners) are those of np.argsort along rows and np.unique of the keys: ranks, orders, groups, each group's
    first island and size."""
    rng = np.random.default_rng(n)
    k = 3000
    ids = np.stack([rng.choice(10 * n, n, replace=False) for _ in range(k)])
    ids[: k // 2] = np.sort(ids[: k // 2], axis=1)  # a common order, as real islands have
    order, rank, first, which, group_size = facevarying._vertex_orders(ids)
    ref_order = np.argsort(ids, axis=1, kind="stable")
    ref_rank = np.argsort(ref_order, axis=1, kind="stable")
    key = (ref_rank * n ** np.arange(n)).sum(axis=1)
    _, ref_first, ref_which, ref_size = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    for got, want in ((order, ref_order), (rank, ref_rank), (first, ref_first), (which, ref_which.reshape(-1)),
                      (group_size, ref_size)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("min_islands", [1, 4])
def test_first_use_numbering_equals_renumbering_the_channel(seed, min_islands, monkeypatch):
    """Islands with a rest (shared values on some faces, rarer vertex orders, a hole): the channel's first-use
    numbering (what the compact vertex order writes) is its own numbering renumbered by first use with the
    unused values left out (the compact order's general renumbering), values bit for bit and indices; its own
    numbering is unchanged (the whole value mesh's values at every corner)."""
    from warp_subdiv.usd.order import OrderedRefiner

    monkeypatch.setattr(facevarying, "MIN_ISLANDS", min_islands)
    rng = np.random.default_rng(seed)
    mesh = polygons_mesh(rng)
    n = len(mesh.face_vertex_indices)
    own = rng.random(len(mesh.face_vertex_counts)) < 0.7
    idx = np.where(np.repeat(own, mesh.face_vertex_counts), mesh.num_vertices + np.arange(n),
                   mesh.face_vertex_indices)
    uv = rng.random((mesh.num_vertices + n, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ws.NonManifoldWarning)
        r = ws.Refiner(mesh, 1 + seed % 2, scheme="catmull-clark", boundary=BOUNDARIES[seed % 3], device="cpu",
                       precision=("float32", "float64")[seed % 2])
        for mode in FVAR_MODES[1:]:
            channel = r.face_varying_channel(idx, mode)
            assert channel.first_use_capable and channel._islands.rest is not None
            values, at = channel.evaluate(uv)
            whole = channel.refiner
            expected = whole.evaluate(uv[channel.source], normal_control=False)[whole.topology()[1]]
            np.testing.assert_array_equal(_bits(values[at]), _bits(expected))
            first, first_at = channel.evaluate(uv, first_use=True)
            renumbered, renumbered_at = OrderedRefiner._face_varying(None, values, at)
            np.testing.assert_array_equal(_bits(first), _bits(renumbered), err_msg=str(mode))
            np.testing.assert_array_equal(first_at, renumbered_at, err_msg=str(mode))
            again, again_at = channel.evaluate(uv)  # (the channel's own numbering again, after the other)
            np.testing.assert_array_equal(_bits(again), _bits(values))
            np.testing.assert_array_equal(again_at, at)
