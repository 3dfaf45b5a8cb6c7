"""Wavefront OBJ in and out, with OpenSubdiv's ``t`` tags and the ``.creases``/``.corners`` side files.

``t crease 2/1/0 v0 v1 sharpness``, ``t corner 1/1/0 v sharpness``, ``t hole 1/0/0 face`` and
``t interpolateboundary 1/0/0 N`` (0 none, 1 edge-and-corner, 2 edge-only) are read, and warp-subdiv's
own ``t concave 2/0/0 c n`` (the sector of corner c that contains edge (c, n) is concave); side files hold lines
``v0 v1 sharpness`` and ``v sharpness`` with 0-based ids. Faces use 1-based (or negative, relative) ids.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from ..errors import SubdivInputError
from ..mesh import Mesh
from ..options import CreaseMethod
from .files import publish

BOUNDARY_FROM_TAG = {0: "none", 1: "edge-and-corner", 2: "edge-only"}


@dataclass
class ObjData:
    """What an OBJ file says: the tagged mesh plus the options its tags ask for ("boundary", "crease_method");
    ``warp_subdiv.usd.options_for`` turns them into a refiner's options."""

    mesh: Mesh
    options: dict = field(default_factory=dict)
    path: str = ""


def _read_side_file(path: str, width: int) -> np.ndarray:
    rows = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            if len(parts) != width:
                raise SubdivInputError(f"{path}:{lineno}: expected {width} values, got {len(parts)}", value=line)
            rows.append([float(p) for p in parts])
    return np.asarray(rows, dtype=np.float64).reshape(-1, width)


def read_obj(path: str) -> ObjData:
    """Read an OBJ file (and its side files) into a :class:`Mesh`."""
    points, counts, indices = [], [], []
    creases, crease_s, corners, corner_s, holes, concave = [], [], [], [], [], []
    options: dict = {}
    try:
        fh = open(path, encoding="utf-8")
    except OSError as exc:
        raise SubdivInputError(f"cannot read {path}: {exc.strerror}") from None
    with fh:
        for lineno, raw in enumerate(fh, 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            try:
                if parts[0] == "v":
                    points.append([float(x) for x in parts[1:4]])
                elif parts[0] == "f":
                    ids = []
                    for tok in parts[1:]:
                        i = int(tok.split("/")[0])
                        ids.append(i - 1 if i > 0 else len(points) + i)
                    counts.append(len(ids))
                    indices.extend(ids)
                elif parts[0] == "t":
                    name = parts[1]
                    nint, nfloat, _ = (int(x) for x in parts[2].split("/"))
                    ints = [int(x) for x in parts[3:3 + nint]]
                    floats = [float(x) for x in parts[3 + nint:3 + nint + nfloat]]
                    if name == "crease":
                        for a, b in zip(ints[:-1], ints[1:]):
                            creases.append((a, b))
                            crease_s.append(floats[0] if floats else 10.0)
                    elif name == "corner":
                        for v in ints:
                            corners.append(v)
                            corner_s.append(floats[0] if floats else 10.0)
                    elif name == "concave":  # warp-subdiv's own tag: corner vertex, neighbour vertex
                        concave.append((ints[0], ints[1]))
                    elif name == "hole":
                        holes.extend(ints)
                    elif name == "interpolateboundary":
                        options["boundary"] = BOUNDARY_FROM_TAG.get(ints[0], "edge-only")
                    elif name == "creasemethod":
                        method = parts[3 + nint] if len(parts) > 3 + nint else "uniform"
                        if method not in CreaseMethod.values():
                            raise SubdivInputError(
                                f"{path}:{lineno}: creasemethod {method!r} is not "
                                f"{' or '.join(CreaseMethod.values())}", value=method)
                        options["crease_method"] = method
            except SubdivInputError:
                raise
            except (ValueError, IndexError):
                raise SubdivInputError(f"{path}:{lineno}: cannot parse {raw.strip()!r}") from None
    stem = os.path.splitext(path)[0]
    if os.path.exists(stem + ".creases"):
        side = _read_side_file(stem + ".creases", 3)
        creases.extend(side[:, :2].astype(np.int64).tolist())
        crease_s.extend(side[:, 2].tolist())
    if os.path.exists(stem + ".corners"):
        side = _read_side_file(stem + ".corners", 2)
        corners.extend(side[:, 0].astype(np.int64).tolist())
        corner_s.extend(side[:, 1].tolist())
    if not points:
        raise SubdivInputError(f"{path}: no vertices")
    mesh = Mesh(
        np.asarray(points, dtype=np.float64).reshape(-1, 3),
        counts,
        indices,
        creases=np.asarray(creases, dtype=np.int64).reshape(-1, 2) if creases else None,
        crease_sharpness=crease_s if creases else None,
        corners=corners or None,
        corner_sharpness=corner_s if corners else None,
        holes=holes or None,
        concave=np.asarray(concave, dtype=np.int64).reshape(-1, 2) if concave else None,
    )
    return ObjData(mesh, options, path)


#: Rows formatted per call: one %-format of a whole chunk (C-level, about 4x faster than np.savetxt's row by row
#: formatting, the same text) with a bounded string.
_CHUNK_ROWS = 1 << 16


def _write_vertices(fh, points: np.ndarray) -> None:
    """``v x y z`` lines (``%.9g`` of the float64 values: float32 points round-trip exactly)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    for start in range(0, len(points), _CHUNK_ROWS):
        chunk = points[start:start + _CHUNK_ROWS]
        fh.write(("v %.9g %.9g %.9g\n" * len(chunk)) % tuple(chunk.ravel().tolist()))


def _write_faces(fh, counts: np.ndarray, idx: np.ndarray) -> None:
    """Face lines of ``counts`` faces with the 1-based vertex numbers ``idx``, a chunk of faces per write."""
    counts = np.asarray(counts, dtype=np.int64)
    idx = np.asarray(idx, dtype=np.int64)
    if not len(counts):
        return
    templates = np.array(["f" + " %d" * c + "\n" for c in range(int(counts.max()) + 1)], dtype=object)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    for start in range(0, len(counts), _CHUNK_ROWS):
        stop = min(start + _CHUNK_ROWS, len(counts))
        fmt = "".join(templates[counts[start:stop]])
        fh.write(fmt % tuple(idx[offsets[start]:offsets[stop]].tolist()))


def _published(path: str, write) -> None:
    """``write(fh)`` into a temporary file beside ``path``, renamed into place once complete (no partial file on
    failure), with the permissions ``open()`` would give the file (:func:`~warp_subdiv.io.files.publish`)."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=".obj", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            write(fh)
        publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_obj(path: str, points: np.ndarray, face_vertex_counts: np.ndarray, face_vertex_indices: np.ndarray) -> None:
    """Write a polygon mesh as OBJ, through a temporary file and a rename (no partial file on failure), with the
    permissions ``open()`` would give the file (:func:`~warp_subdiv.io.files.publish`)."""

    def write(fh):
        fh.write(f"# warp-subdiv: {len(points)} vertices, {len(face_vertex_counts)} faces\n")
        _write_vertices(fh, points)
        _write_faces(fh, face_vertex_counts, np.asarray(face_vertex_indices, dtype=np.int64) + 1)

    _published(path, write)


def write_obj_tiles(path: str, tiles, header: str = "") -> tuple[int, int]:
    """Write the tiles of a tiled refinement (:func:`warp_subdiv.refine_tiled`) into one OBJ file as they come:
    each tile's vertices that no earlier tile wrote, then its faces. A vertex shared by tiles (``border``, with
    the same ``vertex_ids`` in each) is written once; OBJ numbers vertices in the order written, so the file's
    vertex order is not ``refine``'s, its faces are ``refine``'s faces in tile order. Only the border vertices'
    numbers are kept between tiles. Through a temporary file and a rename, as :func:`write_obj`. Returns
    (vertices, faces) written."""
    totals = [0, 0]

    def write(fh):
        if header:
            fh.write(f"# {header}\n")
        known_ids = np.zeros(0, dtype=np.int64)  # border vertices written so far, sorted, and their numbers
        known_numbers = np.zeros(0, dtype=np.int64)
        for tile in tiles:
            ids = np.asarray(tile.vertex_ids, dtype=np.int64)
            border = np.asarray(tile.border, dtype=bool)
            numbers = np.empty(len(ids), dtype=np.int64)
            pos = np.minimum(np.searchsorted(known_ids, ids[border]), max(len(known_ids) - 1, 0))
            found = np.zeros(int(border.sum()), bool) if not len(known_ids) else known_ids[pos] == ids[border]
            seen = np.zeros(len(ids), bool)
            seen[np.flatnonzero(border)[found]] = True
            numbers[seen] = known_numbers[pos[found]]
            new = np.flatnonzero(~seen)
            numbers[new] = totals[0] + 1 + np.arange(len(new))
            _write_vertices(fh, tile.points[new])
            totals[0] += len(new)
            fresh_border = new[border[new]]
            if len(fresh_border):
                known_ids = np.concatenate([known_ids, ids[fresh_border]])
                known_numbers = np.concatenate([known_numbers, numbers[fresh_border]])
                order = np.argsort(known_ids, kind="stable")
                known_ids, known_numbers = known_ids[order], known_numbers[order]
            _write_faces(fh, tile.face_vertex_counts, numbers[np.asarray(tile.face_vertex_indices)])
            totals[1] += len(tile.face_vertex_counts)

    _published(path, write)
    return totals[0], totals[1]
