"""The patch tree of a :class:`~warp_subdiv.limit.LimitSurface`: Bezier patches over a quadtree per base face.

How the limit surface over a base face is represented (docs/limit-surface.md, docs in :mod:`warp_subdiv.limit`):

* A face whose limit surface is a polynomial patch is one leaf: a bicubic B-spline patch (Catmull-Clark) or a
  quartic box-spline patch (Loop), converted to Bezier form (16 or 15 control points). Regular creases,
  boundaries and Catmull-Clark corners are polynomial too (B-spline phantom points; Loop's boundary phantoms
  by the parallelogram rule). Which faces these are: :mod:`warp_subdiv.limit.regular`; the Bezier forms:
  :mod:`warp_subdiv.limit.bezier`.
* Every other face is split into its four children (its sub-faces one level finer) and each child is
  classified again, down to ``depth`` levels below the base face. The children are computed by *local*
  refinement: the faces still to refine and ``MARGIN`` rings of faces around them are cut out of the level
  (tags, sharpness and sector data carried over), refined one step with the library's own tables
  (:func:`~warp_subdiv.tables.build_stencils`, :func:`~warp_subdiv.topology.refine_level`, flatness and
  normal-control projections), and only the children of the cut-out's inner faces are kept. So the
  evaluated surface is the surface ``refine`` converges to, with either rule set
  (:mod:`warp_subdiv.limit.local_refinement`).
* A face still irregular at ``depth`` becomes an *end cap*: a bicubic (Catmull-Clark) or quartic triangular
  (Loop) Bezier patch that interpolates the exact limit positions of its corners (limit masks, one level
  deeper as ``Refiner.limit_points``), their exact tangent planes, and per corner and edge a derivative
  along the edge: the exact one at regular corners (B-spline / box-spline masks), else the derivative of the
  parabola through the exact limit points at the edge's ends and middle, projected onto the tangent plane
  (:mod:`warp_subdiv.limit.end_caps`). At extraordinary boundary and crease vertices the end caps are evaluated
  exactly instead, from the self-similar step of the vertex's two-ring (:mod:`warp_subdiv.limit.exact_caps`;
  the tree's ``exact``).

A face of the control mesh that is a hole (or that ``boundary="none"`` leaves out) is a hole leaf. This module
holds the tree and its builder (:func:`build`).

Parameterisation of the tree (``LimitSurface`` maps base-face (u, v) onto it): a quad node's children are its
quadrants in corner order (0: [0, 1/2]^2, 1: u >= 1/2, 2: both >= 1/2, 3: v >= 1/2); a triangle node's
children are its corner triangles 0..2 and the middle triangle 3, whose frame is turned by 180 degrees
(s = 1 - 2u, t = 1 - 2v).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mesh import Mesh
from ..options import Options, Scheme
from ..tables import Hierarchy
from ..topology import Level, base_faces
from ..topology.connectivity import connectivity
from .bezier import regular_bezier
from .end_caps import end_cap_nets
from .exact_caps import ExactCaps, build_exact_caps
from .exact_caps import link as link_exact_caps
from .local_refinement import LocalLevel, child_faces, cut_out, refine_step, region_around
from .regular import LevelLookups, phantom_points, regular_faces


#: Rings of context faces cut out around the faces refined locally. The artificial boundary of a cut-out
#: changes the rules of its outermost ring of faces; after one step its influence reaches less than one and a
#: half rings of the parent level inward (vertex, edge and flatness rules at the cut), so children of faces
#: three or more rings inside are exact, and a child's one-ring stays inside the exact region for the next
#: step. Four rings keep a ring of slack (tested against uniform refinement).
MARGIN = 4

#: Leaf markers in ``node_patch``.
SPLIT, HOLE = -1, -2

#: Patch kinds.
REGULAR, END_CAP = 0, 1

#: Patch bases: uniform cubic B-spline over 16 indexed points, or Bezier (bicubic / quartic triangular).
BSPLINE, BEZIER = 0, 1



def is_manifold(mesh: Mesh, options: Options) -> bool:
    """Whether the control faces (as ``options`` subdivide them) have no non-manifold edge or vertex."""
    faces = base_faces(mesh, options.scheme, options.boundary, True)
    return not connectivity(faces, mesh.num_vertices).nonmanifold_vert.any()


# ----------------------------------------------------------------------------------------- the tree
@dataclass
class PatchTree:
    """Nodes (quadtree per base face or sub-face), leaves' patches, and the roots of every base face.

    ``node_child`` (N, 4) int32: children of split nodes (-1 for leaves); ``node_patch`` (N,) int32: the patch
    of a leaf, ``SPLIT`` or ``HOLE``. Patches: ``patch_basis`` (P,) int32, ``BSPLINE`` (patches without sharp
    sides: 16 uniform cubic B-spline control points under Catmull-Clark, 12 quartic box-spline control points in
    ``TRI_RING`` order under Loop) or ``BEZIER`` (16 bicubic or 15 quartic triangular Bezier control points);
    ``patch_index`` (P, 16) int32: the control points, rows of
    ``points`` (V, 3) float64 (the control mesh's points, then refined points and Bezier nets; 3 + k columns
    with :func:`build`'s ``data``), in the order
    of ``QUAD_GRID`` / ``TRI_BEZIER_INDEX`` (triangles use the first 15); ``patch_kind`` (P,) int8
    ``REGULAR`` or ``END_CAP``; ``patch_level`` (P,) int8: the level of the patch's face below its base face.
    Roots: base face f (a level-0 face) owns nodes ``root_offsets[f]`` .. ``root_offsets[f + 1] - 1``: one
    node, or its sub-faces (a Catmull-Clark n-gon: the level-1 quad at each corner, in corner order).
    ``exact``: the end caps evaluated exactly (:class:`~warp_subdiv.limit.exact_caps.ExactCaps`), or None.
    """

    scheme: str
    triangles: bool
    node_child: np.ndarray
    node_patch: np.ndarray
    points: np.ndarray
    patch_index: np.ndarray
    patch_basis: np.ndarray
    patch_kind: np.ndarray
    patch_level: np.ndarray
    root_offsets: np.ndarray
    depth: int
    stats: dict = field(default_factory=dict)
    exact: ExactCaps | None = None

    @property
    def num_nodes(self) -> int:
        return len(self.node_patch)

    @property
    def num_patches(self) -> int:
        return len(self.patch_kind)


class _Nodes:
    """Growable node arrays."""

    def __init__(self):
        self.child = [np.zeros((0, 4), np.int32)]
        self.patch = [np.zeros(0, np.int32)]
        self.count = 0

    def new(self, n: int) -> np.ndarray:
        ids = np.arange(self.count, self.count + n, dtype=np.int64)
        self.child.append(np.full((n, 4), -1, np.int32))
        self.patch.append(np.full(n, SPLIT, np.int32))
        self.count += n
        return ids

    def freeze(self):
        self.child = [np.concatenate(self.child)]
        self.patch = [np.concatenate(self.patch)]
        return self.child[0], self.patch[0]

    def set_patch(self, node_ids, values) -> None:
        self.freeze()
        self.patch[0][np.asarray(node_ids, dtype=np.int64)] = values

    def set_children(self, node_ids, children) -> None:
        self.freeze()
        self.child[0][np.asarray(node_ids, dtype=np.int64)] = children


class _Patches:
    """Growable patch arrays and the global point array their control points index."""

    def __init__(self, width: int = 3):
        self.width = width
        self.index, self.basis, self.kind, self.level = [], [], [], []
        self.points = []
        self.num_points = 0
        self.count = 0

    def add_points(self, points: np.ndarray) -> int:
        """Append points; returns the index of the first."""
        first = self.num_points
        self.points.append(np.asarray(points, dtype=np.float64).reshape(-1, self.width))
        self.num_points += len(self.points[-1])
        return first

    def add_indexed(self, index: np.ndarray, basis: int, kind: int, level: int) -> np.ndarray:
        n = len(index)
        full = np.zeros((n, 16), dtype=np.int64)
        full[:, :index.shape[1]] = index
        self.index.append(full)
        self.basis.append(np.full(n, basis, np.int32))
        self.kind.append(np.full(n, kind, np.int8))
        self.level.append(np.full(n, level, np.int8))
        ids = np.arange(self.count, self.count + n, dtype=np.int64)
        self.count += n
        return ids

    def add_bezier(self, nets: np.ndarray, kind: int, level: int) -> np.ndarray:
        """Patches whose Bezier nets (n, 16 or 15, width) are appended to the points."""
        n, m = nets.shape[:2]
        first = self.add_points(nets.reshape(-1, self.width))
        index = first + np.arange(n * m, dtype=np.int64).reshape(n, m)
        return self.add_indexed(index, BEZIER, kind, level)

    def arrays(self):
        def cat(parts, shape, dtype):
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)
        return (cat(self.points, (0, self.width), np.float64), cat(self.index, (0, 16), np.int32),
                cat(self.basis, (0,), np.int32), cat(self.kind, (0,), np.int8), cat(self.level, (0,), np.int8))


# ----------------------------------------------------------------------------------------- building
def build(mesh: Mesh, options: Options, depth: int, *, data: np.ndarray | None = None) -> PatchTree:
    """The patch tree of ``mesh`` with ``options``: irregular faces refined locally down to ``depth`` levels
    below their base face (``depth`` >= 1), end caps below that.

    ``data`` (V, k) float64: per-vertex data carried beside the positions: the tree's ``points`` then have
    3 + k columns, the data's Bezier and B-spline control values after the positions'. Every decision that
    depends on geometry (sector angles, end caps' tangent planes, sectors of several-sector corners) is taken
    from the positions, and each data column goes through the same linear operations as a position column
    (flatness included, normal control not, as ``Refiner.evaluate`` refines primvars): the data's control
    values are a linear function of ``data`` with the positions' weights, and a data column equal to a position
    column gets the same bits where normal control is off."""
    o = options
    scheme = o.scheme.value if isinstance(o.scheme, Scheme) else str(o.scheme)
    triangles = o.scheme == Scheme.LOOP
    n = 3 if triangles else 4
    hierarchy = Hierarchy(mesh, 0, o)
    level0 = hierarchy.final
    manifold = is_manifold(mesh, o)
    normal_ids = hierarchy.normal_vertices.astype(np.int64)
    if o.normal_strength <= 0:
        normal_ids = normal_ids[:0]
    normal_vectors = np.asarray(hierarchy.normal_vectors, dtype=np.float64).reshape(-1, 3)[:len(normal_ids)]
    nodes = _Nodes()
    base_points = np.asarray(mesh.points, dtype=np.float64)
    if data is not None:
        base_points = np.concatenate([base_points, np.asarray(data, dtype=np.float64).reshape(len(base_points), -1)],
                                     axis=1)
    patches = _Patches(base_points.shape[1])
    patches.add_points(base_points)
    F0 = level0.num_faces
    sizes0 = level0.face_sizes()
    direct = sizes0 == n
    root_count = np.where(direct, 1, sizes0)
    root_offsets = np.concatenate([[0], np.cumsum(root_count)]).astype(np.int64)
    nodes.new(int(root_offsets[-1]))
    stats = {"levels": [], "end_caps": 0, "exact_end_caps": 0, "regular_base_faces": 0}
    exact = None
    face_node = np.full(F0, -1, dtype=np.int64)
    face_node[direct] = root_offsets[:-1][direct]
    cur = LocalLevel(level0, base_points, face_node, normal_ids, normal_vectors, 0)
    todo = _classify(nodes, patches, cur, np.flatnonzero(direct), o, scheme)
    stats["regular_base_faces"] = int(direct.sum() - len(todo))
    # n-gons (Catmull-Clark): the face itself is refined; its sub-faces (level 1) are its roots
    polygon_faces = np.flatnonzero(~direct)
    todo = np.union1d(todo, polygon_faces).astype(np.int64)
    while len(todo):
        last = cur.depth >= depth
        # a manifold mesh is cut out even where the region is the whole level: a cut-out is rebuilt from its
        # faces, and some of its stencils sum in another order than the level's own, so refining the level
        # itself where the region covers it would make a face's patches depend (in the last bits) on how far
        # the mesh extends; cut out always, they depend on the face's neighbourhood only, and a submesh with a
        # halo (tiled tessellation) has the whole mesh's patches bit for bit. (A cut-out does not keep
        # non-manifold edges and fans as they are: a non-manifold mesh is refined whole where it can be.)
        region = region_around(cur.level, todo, MARGIN)
        if region.all() and not manifold:
            sub, sub_todo, region_faces = cur, todo, None
        else:
            sub = cut_out(cur, region, o)
            region_faces = np.flatnonzero(region)
            sub_todo = np.searchsorted(region_faces, todo)
        child, child_points = refine_step(sub, o)
        if last:
            caps = end_cap_nets(sub, child, child_points, sub_todo, o)
            nodes.set_patch(sub.face_node[sub_todo], patches.add_bezier(caps, END_CAP, cur.depth))
            stats["end_caps"] = len(caps)
            break
        if cur.depth == depth - 1 and depth >= 2:  # the faces whose children are the end caps: exact caps' anchors
            exact = build_exact_caps(sub, sub_todo, o, MARGIN)
        child_node = _child_nodes(nodes, sub, sub_todo, child, region_faces, root_offsets, sizes0, scheme)
        nxt = LocalLevel(child, child_points, child_node, sub.normal_ids, sub.normal_vectors, cur.depth + 1)
        todo = _classify(nodes, patches, nxt, np.flatnonzero(child_node >= 0), o, scheme)
        stats["levels"].append({"level": nxt.depth, "faces_refined": int(sub.level.num_faces),
                                "irregular": int(len(todo))})
        cur = nxt
    node_child, node_patch = nodes.freeze()
    left = np.flatnonzero((node_patch == SPLIT) & np.any(node_child < 0, axis=1))
    if len(left):
        raise AssertionError(f"{len(left)} patch tree nodes were left without a patch")
    points, index, basis, kind, plevel = patches.arrays()
    exact = link_exact_caps(exact, node_child, node_patch, kind, END_CAP)
    stats["exact_end_caps"] = 0 if exact is None else exact.num_caps
    return PatchTree(scheme, triangles, node_child, node_patch, points, index, basis, kind, plevel, root_offsets,
                     depth, stats, exact)


def _classify(nodes: _Nodes, patches: _Patches, local: LocalLevel, faces: np.ndarray, options: Options,
              scheme: str) -> np.ndarray:
    """Make leaves of the hole and regular faces among ``faces`` of ``local``; returns the others (to refine)."""
    fnode = local.face_node[faces]
    hole = local.level.face_hole[faces]
    nodes.set_patch(fnode[hole], HOLE)
    faces, fnode = faces[~hole], fnode[~hole]
    topo = LevelLookups(local.level, options, local.normal_ids)
    ok, ids, side_sharp = regular_faces(topo, faces, scheme)
    if ok.any():
        ids, side_sharp, fn = ids[ok], side_sharp[ok], fnode[ok]
        plain = ~side_sharp.any(axis=1)
        if plain.any():  # B-spline / box-spline patches over the level's own points
            if local.depth == 0:
                index = ids[plain]
            else:
                used, inverse = np.unique(ids[plain], return_inverse=True)
                index = patches.add_points(local.points[used]) + inverse.reshape(-1, ids.shape[1])
            nodes.set_patch(fn[plain], patches.add_indexed(index, BSPLINE, REGULAR, local.depth))
        rest = ~plain
        if rest.any():
            control = phantom_points(local.points, ids[rest], side_sharp[rest], scheme)
            nodes.set_patch(fn[rest], patches.add_bezier(regular_bezier(control, scheme), REGULAR, local.depth))
    return faces[~ok]


def _child_nodes(nodes: _Nodes, sub: LocalLevel, sub_todo: np.ndarray, child: Level, region_faces,
                 root_offsets: np.ndarray, sizes0: np.ndarray, scheme: str) -> np.ndarray:
    """The tree node of every face of ``child`` (the refined ``sub``), -1 for context faces: the children of
    the split faces ``sub_todo`` get new nodes, those of an n-gon base face are its roots. ``region_faces``:
    the level's face of each face of a cut-out ``sub`` (None when ``sub`` is the whole level)."""
    kids, _ = child_faces(sub.level, sub_todo, scheme)
    child_node = np.full(child.num_faces, -1, dtype=np.int64)
    tn = sub.face_node[sub_todo]
    rows = np.flatnonzero(tn >= 0)
    # split quad nodes: four children each. Without any (level 0 of a mesh of triangles only) ``kids`` is only
    # as wide as the largest face, three columns, and has no fourth child to link.
    if len(rows):
        new = nodes.new(4 * len(rows)).reshape(-1, 4)
        nodes.set_children(tn[rows], new)
        for j in range(4):
            child_node[kids[rows, j]] = new[:, j]
    for r in np.flatnonzero(tn < 0):  # n-gon base faces (level 0 only): their roots
        f = int(sub_todo[r] if region_faces is None else region_faces[sub_todo[r]])
        for j in range(int(sizes0[f])):
            child_node[kids[r, j]] = root_offsets[f] + j
    return child_node
