"""The tagged control mesh: points, polygons, creases, corners, concave sectors, normals and holes.

Everything a user hands in is validated here, so that later stages can trust their input. Errors are
:class:`SubdivInputError` (a ``ValueError``) and name the face, vertex, edge or tag at fault; their fields say
the same in structured form: ``option`` is the :class:`Mesh` argument at fault (``"points"``,
``"face_vertex_counts"``, ``"face_vertex_indices"``, ``"creases"``, ``"crease_sharpness"``, ``"corners"``,
``"corner_sharpness"``, ``"concave"``, ``"normals"``, ``"holes"``), ``element`` and ``index`` the element
("vertex", "face", "crease", "corner", "concave", "normal", "hole") and its place in that argument.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from .checks import NOT_NUMBERS, first_non_number
from .errors import SubdivInputError

#: Sharpness at or above this value is infinitely sharp (as in USD and OpenSubdiv).
INFINITE_SHARPNESS = 10.0


@dataclass(frozen=True)
class MeshEdges:
    """The control mesh's edges, in OpenSubdiv's order (order of first appearance around the faces).

    ``corner_edge[h]`` is the edge from corner ``h`` to the next corner of the same face;
    ``edge_verts[e]`` is oriented as first met. ``sorted_keys``/``sorted_ids`` look edges up by vertex pair
    (the first instance of a pair that has several). As OpenSubdiv's ``Vtr::Level`` builds them, a corner whose
    two vertices are the same makes a degenerate edge of its own, and a face that uses a vertex pair again
    (after its first use of that pair) makes a new instance of the edge; ``nonmanifold`` flags those edges
    and the first instance of every pair that has several (OpenSubdiv's edge tag, as built).
    """

    corner_next: np.ndarray
    corner_edge: np.ndarray
    edge_verts: np.ndarray
    sorted_keys: np.ndarray
    sorted_ids: np.ndarray
    nonmanifold: np.ndarray | None = None  # (E,) bool; None: no edge is flagged
    repeat_faces: np.ndarray | None = None  # the faces that use some vertex more than once (None: not known)

    def find(self, pairs: np.ndarray, num_vertices: int) -> np.ndarray:
        """Edge ids of vertex pairs (m, 2); -1 where the pair is not an edge (a pair with several instances:
        the first, as OpenSubdiv's ``FindEdge``)."""
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        keys = np.minimum(pairs[:, 0], pairs[:, 1]) * num_vertices + np.maximum(pairs[:, 0], pairs[:, 1])
        pos = np.searchsorted(self.sorted_keys, keys)
        pos = np.minimum(pos, len(self.sorted_keys) - 1)
        found = self.sorted_keys[pos] == keys if len(self.sorted_keys) else np.zeros(len(keys), bool)
        return np.where(found, self.sorted_ids[pos], -1).astype(np.int64)


def face_offsets_of(counts: np.ndarray) -> np.ndarray:
    """Start of each face in the flat corner list, plus the total at the end."""
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets


def expand_counts(counts: np.ndarray):
    """For a list of groups of the given sizes: (group of each item, rank of the item inside its group)."""
    counts = np.asarray(counts, dtype=np.int64)
    group = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    rank = np.arange(len(group), dtype=np.int64) - np.repeat(face_offsets_of(counts)[:-1], counts)
    return group, rank


def next_corner_of(counts: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """For every corner, the next corner of the same face (wrapping around)."""
    total = int(offsets[-1])
    nxt = np.arange(1, total + 1, dtype=np.int64)
    last = offsets[1:] - 1
    nxt[last] = offsets[:-1]
    return nxt


def faces_with_repeats(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(F,) bool: faces that use some vertex more than once."""
    counts = np.asarray(counts, dtype=np.int64)
    F = len(counts)
    if F and np.all(counts == counts[0]) and counts[0] <= 8:  # one face size: compare columns
        n = int(counts[0])
        v = np.asarray(indices).reshape(F, n)
        out = np.zeros(F, dtype=bool)
        for i in range(n):
            for j in range(i + 1, n):
                out |= v[:, i] == v[:, j]
        return out
    face = np.repeat(np.arange(F, dtype=np.int64), counts)
    order = np.lexsort((indices, face))
    same = (face[order][1:] == face[order][:-1]) & (np.asarray(indices)[order][1:] == np.asarray(indices)[order][:-1])
    out = np.zeros(F, dtype=bool)
    out[face[order][1:][same]] = True
    return out


def find_edges(counts: np.ndarray, indices: np.ndarray, num_vertices: int) -> MeshEdges:
    """Discover the edges of a polygon mesh (level 0 only; refined levels derive theirs by index arithmetic).

    As ``Vtr::Level::completeTopologyFromFaceVertices``: walking the corners in order, a corner makes a new
    edge when its vertex pair has none yet, when its two vertices are the same (a degenerate edge), or when its
    face has used the pair before (a repeated edge in a face); otherwise it joins the pair's first edge. Edge ids
    follow the corners that make them."""
    counts = np.asarray(counts, dtype=np.int64)
    offsets = face_offsets_of(counts)
    nxt = next_corner_of(counts, offsets)
    a = indices.astype(np.int64)
    b = a[nxt]
    C = len(a)
    keys = np.minimum(a, b) * num_vertices + np.maximum(a, b)
    uniq, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    degenerate = a == b
    makes = np.zeros(C, dtype=bool)
    makes[first] = True
    makes |= degenerate
    repeated = np.zeros(C, dtype=bool)
    odd = np.flatnonzero(faces_with_repeats(counts, a))
    if len(odd):  # only a face that uses a vertex twice can use a vertex pair twice
        h = np.concatenate([np.arange(offsets[f], offsets[f + 1]) for f in odd])
        face = np.repeat(odd, counts[odd])
        order = np.lexsort((h, keys[h], face))
        again = (face[order[1:]] == face[order[:-1]]) & (keys[h][order[1:]] == keys[h][order[:-1]])
        repeated[h[order[1:][again]]] = True
        repeated &= ~degenerate
        makes |= repeated
    rank = np.cumsum(makes) - 1  # edge id made at each making corner
    corner_edge = np.where(makes, rank, rank[first[inverse]])
    makers = np.flatnonzero(makes)
    edge_verts = np.stack([a[makers], b[makers]], axis=1)
    nonmanifold = None
    if np.any(degenerate) or np.any(repeated):
        nonmanifold = np.zeros(len(makers), dtype=bool)
        nonmanifold[rank[degenerate]] = True
        nonmanifold[rank[repeated]] = True
        nonmanifold[rank[first[inverse[repeated]]]] = True  # the first instance of a repeated pair
    return MeshEdges(
        corner_next=nxt,
        corner_edge=corner_edge.astype(np.int32),
        edge_verts=edge_verts.astype(np.int32),
        sorted_keys=uniq,
        sorted_ids=rank[first],
        nonmanifold=nonmanifold,
        repeat_faces=odd,
    )


#: Integers beyond this magnitude are out of range for every index; they are clamped to it on conversion to
#: int64 (so range checks still fail) and reported as given (:func:`_given`).
_HUGE = 2**62


def _int_array(value, name: str, shape_tail: tuple = (), option: str | None = None) -> np.ndarray:
    """``value`` as int64 of shape (n,) + shape_tail; ``name`` says it in messages, ``option`` (default
    ``name``) is the Mesh argument it came from. Integers too large for int64 (1e20, 2**64 - 1) become +-2**62,
    out of range of every index, so the range checks report them (with the value given: :func:`_given`)."""
    option = option or name
    arr = np.asarray(value)
    if arr.size == 0:
        return np.zeros((0,) + shape_tail, dtype=np.int64)
    if arr.dtype.kind == "f":
        bad = np.flatnonzero(~np.isfinite(arr) | (arr != np.round(arr)))
        if len(bad):
            raise SubdivInputError(f"{name} must hold integers, got {arr.flat[bad[0]]!r}", option=option,
                                   value=arr.flat[bad[0]].item())
        arr = np.clip(arr, -_HUGE, _HUGE)
    elif arr.dtype.kind == "u":
        arr = np.minimum(arr, np.uint64(_HUGE))
    elif arr.dtype.kind == "O" and all(isinstance(x, numbers.Integral) and not isinstance(x, bool)
                                       for x in arr.flat):
        arr = np.array([min(max(int(x), -_HUGE), _HUGE) for x in arr.flat], dtype=np.int64).reshape(arr.shape)
    elif arr.dtype.kind not in "iu":
        raise SubdivInputError(f"{name} must hold integers, got dtype {arr.dtype}", option=option)
    arr = arr.astype(np.int64)
    if shape_tail:
        if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
            raise SubdivInputError(f"{name} must have shape (n, {', '.join(map(str, shape_tail))}), got {arr.shape}",
                                   option=option)
    elif arr.ndim != 1:
        raise SubdivInputError(f"{name} must be one-dimensional, got shape {arr.shape}", option=option)
    return arr


def _given(value, flat: int):
    """Entry ``flat`` of the flattened argument ``value`` as the caller gave it (a Python number), for
    messages: 1e20 stays 1e+20 rather than what it becomes in int64."""
    item = np.asarray(value).reshape(-1)[flat]
    item = item.item() if isinstance(item, np.generic) else item
    if isinstance(item, float) and item == int(item) and abs(item) < _HUGE:
        return int(item)
    return item


def _check_vertex_ids(ids: np.ndarray, num_vertices: int, name: str, element: str, option: str | None = None,
                      given=None) -> None:
    """Every id a vertex; else an error naming the entry (``element`` ``index``: the row of the argument) and
    its value as given (``given``: the argument as passed, default ``ids``)."""
    bad = np.flatnonzero((ids < 0) | (ids >= num_vertices))
    if len(bad):
        flat = int(bad[0])
        where = tuple(int(i) for i in np.unravel_index(flat, ids.shape))
        value = _given(ids if given is None else given, flat)
        raise SubdivInputError(
            f"{name} entry {where[0] if len(where) == 1 else list(where)} is vertex {value}, "
            f"outside [0, {num_vertices})",
            option=option or name, element=element, index=where[0], value=value,
        )


def _refuse_items_that_are_not_numbers(values, name: str, element: str) -> None:
    """Refuse a sharpness argument that is, or holds, a bool, a string or a complex number (a numpy array of such
    a dtype, or a sequence with one among numbers), naming ``name`` and the tag (``element`` and its index)."""
    if isinstance(values, NOT_NUMBERS):
        raise SubdivInputError(f"{name} must hold numbers (one per tag, or one for all), got {values!r} (a bool, a "
                               "string or a complex number is not a sharpness)", option=name, value=values)
    found = first_non_number(values)
    if found is None:
        return
    index, item = found
    raise SubdivInputError(f"{name} must hold numbers (one per tag), got {item!r} for {element} {index} (a bool, a "
                           "string or a complex number is not a sharpness)", option=name, element=element,
                           index=index, value=item)


def _sharpness(values, count: int, name: str, element: str) -> np.ndarray:
    """One finite sharpness >= 0 per tag (float64, capped at :data:`INFINITE_SHARPNESS`): ``values`` one number
    per tag, one number for all, or None (infinitely sharp)."""
    if values is None:
        return np.full(count, INFINITE_SHARPNESS)
    _refuse_items_that_are_not_numbers(values, name, element)
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise SubdivInputError(f"{name} must be a number or one number per tag, got {values!r}",
                               option=name) from None
    if arr.ndim == 0:  # one number for every tag
        arr = np.full(count, float(arr))
    if arr.ndim != 1 or len(arr) != count:
        raise SubdivInputError(f"{name} has {arr.size} values for {count} tags; give one per tag (or a single "
                               "number for all)", option=name, value=arr.shape)
    bad = np.flatnonzero(~np.isfinite(arr) | (arr < 0))
    if len(bad):
        raise SubdivInputError(f"{name}[{bad[0]}] = {arr[bad[0]]} is not a finite sharpness >= 0", option=name,
                               element=element, index=int(bad[0]), value=float(arr[bad[0]]))
    return np.minimum(arr, INFINITE_SHARPNESS)


#: The largest magnitude of data a refiner of each precision takes (``check_rows(bound=)``): refinement sums
#: weighted values and limit normals multiply tangents, so data near the type's range would overflow to
#: infinity; beyond these bounds it is refused instead (a float64 refiner takes up to 1e150).
DATA_BOUND = {"float32": 1e18, "float64": 1e150}


def check_rows(data, rows: int, what: str, *, at_least: bool = False, bound: float | None = None) -> np.ndarray:
    """Per-vertex (or per-value) data as a finite real array (rows, d), d >= 1 ((rows,) becomes (rows, 1));
    ``at_least``: any number of rows >= ``rows``; ``bound``: the largest magnitude allowed (:data:`DATA_BOUND`).
    Else :class:`SubdivInputError` (``element`` "data") naming ``what`` and the shape, the dtype or the first
    row that is not finite or too large."""
    try:
        arr = np.asarray(data)
        if arr.dtype.kind == "O":
            arr = arr.astype(np.float64)
    except (TypeError, ValueError):
        raise SubdivInputError(f"{what} must be an array of real numbers ({rows}, d)", element="data") from None
    if arr.dtype.kind not in "biuf":
        raise SubdivInputError(f"{what} must hold real numbers, got dtype {arr.dtype}", element="data",
                               value=str(arr.dtype))
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] < 1 or (arr.shape[0] < rows if at_least else arr.shape[0] != rows):
        need = f"at least {rows} rows" if at_least else f"shape ({rows}, d)"
        raise SubdivInputError(f"{what} must have {need} with d >= 1, got {np.shape(data)}",
                               element="data", value=np.shape(data))
    finite = np.all(np.isfinite(arr), axis=1)
    if not np.all(finite):
        bad = int(np.flatnonzero(~finite)[0])
        raise SubdivInputError(f"{what} row {bad} is not finite", element="data", index=bad)
    if bound is not None and arr.size:
        big = np.max(np.abs(arr), axis=1) > bound
        if np.any(big):
            bad = int(np.flatnonzero(big)[0])
            precision = next((k for k, v in DATA_BOUND.items() if v == bound), None)
            hint = (" (precision='float64' takes up to 1e150)" if precision == "float32" else
                    "; scale the data down")
            raise SubdivInputError(f"{what} row {bad} has a value of magnitude {float(np.max(np.abs(arr[bad]))):.3g}, "
                                   f"beyond the {bound:g} that {precision or 'this'} refinement takes{hint}",
                                   element="data", index=bad, value=float(np.max(np.abs(arr[bad]))))
    return arr


def _refuse_coordinates_that_are_not_numbers(values, option: str, element: str) -> None:
    """Refuse rows of coordinates (points, prescribed normals) holding a bool, a string or a complex number,
    which numpy would turn into a coordinate without a word, naming the row."""
    found = first_non_number(values)
    if found is None:
        return
    index, item = found
    try:
        row = index // 3 if np.shape(values)[-1:] == (3,) else None
    except ValueError:  # ragged rows: no row to name
        row = None
    where = f" ({element} {row})" if row is not None else ""
    raise SubdivInputError(f"{option} must hold real numbers, got {item!r}{where}: a bool, a string or a complex "
                           "number is not a coordinate", option=option, element=element, index=row, value=item)


def _checked_points(points) -> np.ndarray:
    """The control points as finite float64 (n, 3)."""
    _refuse_coordinates_that_are_not_numbers(points, "points", "vertex")
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise SubdivInputError("points must be an array of real numbers of shape (n, 3)", option="points") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise SubdivInputError(f"points must have shape (n, 3), got {pts.shape}", option="points")
    bad = np.flatnonzero(~np.all(np.isfinite(pts), axis=1))
    if len(bad):
        raise SubdivInputError(f"point {bad[0]} is not finite: {pts[bad[0]].tolist()}", option="points",
                               element="vertex", index=int(bad[0]))
    return pts


def _checked_faces(face_vertex_counts, face_vertex_indices, num_vertices: int):
    """(counts, indices) as int64 and the face offsets: at least one face, every face of three or more corners,
    counts that add up to the indices, every index a vertex, and few enough corners for 32-bit tables."""
    counts = _int_array(face_vertex_counts, "face_vertex_counts")
    indices = _int_array(face_vertex_indices, "face_vertex_indices")
    if len(counts) == 0:
        raise SubdivInputError("the mesh has no faces", option="face_vertex_counts")
    small = np.flatnonzero(counts < 3)
    if len(small):
        raise SubdivInputError(f"face {small[0]} has {counts[small[0]]} vertices; a face needs at least 3",
                               option="face_vertex_counts", element="face", index=int(small[0]),
                               value=int(counts[small[0]]))
    if int(counts.sum()) != len(indices):
        raise SubdivInputError(
            f"face_vertex_counts add up to {int(counts.sum())} but face_vertex_indices has {len(indices)} entries",
            option="face_vertex_counts",
        )
    if len(indices) >= 2**31 // 16:
        raise SubdivInputError(f"{len(indices)} face-vertex indices exceed what 32-bit tables can refine",
                               option="face_vertex_indices")
    offsets = face_offsets_of(counts)
    corner_face = np.repeat(np.arange(len(counts)), counts)
    out = np.flatnonzero((indices < 0) | (indices >= num_vertices))
    if len(out):
        h = out[0]
        f = corner_face[h]
        raise SubdivInputError(
            f"face {f} corner {h - offsets[f]} refers to vertex {_given(face_vertex_indices, h)}, outside "
            f"[0, {num_vertices})",
            option="face_vertex_indices", element="face", index=int(f), value=_given(face_vertex_indices, h),
        )
    # faces that use a vertex more than once are accepted, as OpenSubdiv accepts them: their repeated
    # vertex pairs and degenerate edges are non-manifold edges (find_edges; topology.base_level)
    return counts, indices, offsets


def _edges_of_pairs(mesh: Mesh, pairs: np.ndarray) -> np.ndarray:
    """Edge ids of vertex pairs (m, 2) (-1: not an edge); the mesh's edges are found only when there are pairs."""
    return mesh.edges.find(pairs, mesh.num_vertices) if len(pairs) else np.zeros(0, np.int64)


def _checked_creases(mesh: Mesh, creases, crease_sharpness):
    """(creases (m, 2) int32, their sharpness, their edge ids): every pair two vertices and an edge of ``mesh``."""
    cr = _int_array(creases if creases is not None else [], "creases", (2,))
    _check_vertex_ids(cr, mesh.num_vertices, "creases", "crease", given=creases)
    cr_sharp = _sharpness(crease_sharpness, len(cr), "crease_sharpness", "crease")
    cr_edges = _edges_of_pairs(mesh, cr)
    missing = np.flatnonzero(cr_edges < 0)
    if len(missing):
        i = missing[0]
        raise SubdivInputError(f"crease {i} ({cr[i, 0]}, {cr[i, 1]}) is not an edge of the mesh",
                               option="creases", element="crease", index=int(i))
    return cr.astype(np.int32), cr_sharp, cr_edges


def _checked_concave(mesh: Mesh, concave):
    """(concave tags (t, 2) int32, their edge ids): every pair two vertices and an edge of ``mesh``."""
    cc = _int_array(concave if concave is not None else [], "concave", (2,))
    _check_vertex_ids(cc, mesh.num_vertices, "concave", "concave", given=concave)
    cc_edges = _edges_of_pairs(mesh, cc)
    missing = np.flatnonzero(cc_edges < 0)
    if len(missing):
        i = missing[0]
        raise SubdivInputError(
            f"concave tag {i} ({cc[i, 0]}, {cc[i, 1]}): the pair is not an edge of the mesh",
            option="concave", element="concave", index=int(i),
        )
    return cc.astype(np.int32), cc_edges


def _checked_normals(normals, num_vertices: int):
    """(vertex ids int32, unit normals (n, 3)) of the prescribed normals (none when ``normals`` is None): a
    pair of vertex ids and normals of length 1 (within 1e-3, then normalised), at most one per vertex."""
    if normals is None:
        return np.zeros(0, np.int32), np.zeros((0, 3))
    try:
        ids, vecs = normals
    except (TypeError, ValueError):
        raise SubdivInputError("normals must be a pair (vertex ids, unit normals)", option="normals") from None
    given_ids = ids
    ids = _int_array(ids, "normals vertex ids", option="normals")
    _check_vertex_ids(ids, num_vertices, "normals vertex ids", "vertex", option="normals", given=given_ids)
    _refuse_coordinates_that_are_not_numbers(vecs, "normals", "normal")
    vecs = np.asarray(vecs, dtype=np.float64)
    if vecs.shape != (len(ids), 3):
        raise SubdivInputError(
            f"normals need shape ({len(ids)}, 3) for {len(ids)} vertex ids, got {vecs.shape}",
            option="normals", element="normal",
        )
    length = np.linalg.norm(vecs, axis=1)
    bad = np.flatnonzero(~np.isfinite(length) | (np.abs(length - 1.0) > 1e-3))
    if len(bad):
        raise SubdivInputError(
            f"prescribed normal for vertex {ids[bad[0]]} has length {length[bad[0]]:.6g}; give unit normals",
            option="normals", element="normal", index=int(bad[0]), value=float(length[bad[0]]),
        )
    uniq, cnt = np.unique(ids, return_counts=True)
    if np.any(cnt > 1):
        vertex = int(uniq[cnt > 1][0])
        raise SubdivInputError(f"vertex {vertex} has more than one prescribed normal", option="normals",
                               element="vertex", index=vertex)
    return ids.astype(np.int32), vecs / length[:, None]


def _checked_holes(holes, num_faces: int) -> np.ndarray:
    """The hole face ids as int32, every one a face."""
    ho = _int_array(holes if holes is not None else [], "holes")
    bad = np.flatnonzero((ho < 0) | (ho >= num_faces))
    if len(bad):
        value = _given(holes, int(bad[0]))
        raise SubdivInputError(f"hole {bad[0]} is face {value}, outside [0, {num_faces})", option="holes",
                               element="hole", index=int(bad[0]), value=value)
    return ho.astype(np.int32)


class Mesh:
    """A polygon control mesh with subdivision tags.

    ``creases``: (m, 2) vertex pairs of tagged edges; ``corners``: vertex ids; their sharpness arrays default
    to infinite (>= 10 means infinitely sharp); ``concave``: (t, 2) pairs (corner vertex, neighbour vertex)
    marking the sector of that corner that contains the edge as concave; ``normals``: a pair
    (vertex ids (n,), unit normals (n, 3)) of prescribed normals; ``holes``: face ids.
    Boundary edges are always creases.
    """

    def __init__(
        self,
        points,
        face_vertex_counts,
        face_vertex_indices,
        *,
        creases=None,
        crease_sharpness=None,
        corners=None,
        corner_sharpness=None,
        concave=None,
        normals=None,
        holes=None,
    ):
        """Validates every argument in this order (points, faces, creases, corners, concave tags, normals,
        holes); the first problem found is raised."""
        self.points = _checked_points(points)
        nv = len(self.points)
        counts, indices, offsets = _checked_faces(face_vertex_counts, face_vertex_indices, nv)
        self.face_vertex_counts = counts.astype(np.int32)
        self.face_vertex_indices = indices.astype(np.int32)
        self.face_offsets = offsets
        self._edges = None  # found on first use (:attr:`edges`): tags need them now, an analysis later

        self.creases, self.crease_sharpness, self.crease_edges = _checked_creases(self, creases, crease_sharpness)
        co = _int_array(corners if corners is not None else [], "corners")
        _check_vertex_ids(co, nv, "corners", "corner", given=corners)
        self.corners = co.astype(np.int32)
        self.corner_sharpness = _sharpness(corner_sharpness, len(co), "corner_sharpness", "corner")
        self.concave, self.concave_edges = _checked_concave(self, concave)
        self.normal_vertices, self.normal_vectors = _checked_normals(normals, nv)
        self.holes = _checked_holes(holes, len(counts))

    @property
    def num_vertices(self) -> int:
        """The number of control vertices."""
        return len(self.points)

    @property
    def num_faces(self) -> int:
        """The number of faces."""
        return len(self.face_vertex_counts)

    @property
    def edges(self) -> MeshEdges:
        """The mesh's edges (:func:`find_edges`), found on first use: building a mesh without crease or
        concave tags does not need them, so the USD reader leaves them to the analysis, which runs on threads.
        (Two threads asking at once each find the same edges.)"""
        if self._edges is None:
            self._edges = find_edges(self.face_vertex_counts, self.face_vertex_indices, len(self.points))
        return self._edges

    @property
    def num_edges(self) -> int:
        """The number of edges (found on first use)."""
        return len(self.edges.edge_verts)

    def is_all(self, size: int) -> bool:
        """True when every face has ``size`` vertices."""
        return bool(np.all(self.face_vertex_counts == size))

    def __repr__(self) -> str:
        return (
            f"Mesh({self.num_vertices} vertices, {self.num_faces} faces, {len(self.creases)} creases, "
            f"{len(self.corners)} corners, {len(self.concave)} concave tags, {len(self.normal_vertices)} normals, "
            f"{len(self.holes)} holes)"
        )
