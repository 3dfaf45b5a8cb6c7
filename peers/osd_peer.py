"""Python side of ``osd_peer``, a small C++ program built against the system's OpenSubdiv (Debian ``libosd-dev``,
OpenSubdiv 3.5): a differential-testing oracle for ``rules="opensubdiv"`` and a benchmark peer.

The program (``peers/osd/osd_peer.cpp``; its header documents the file format and every option exactly) is
built on demand with ``peers/osd/build.sh`` into ``peers/osd/build/osd_peer`` (ignored by git) when it is
missing or older than its source and OpenSubdiv's headers are installed (``peers/install_osd.sh`` installs
them with apt). ``OSD_PEER_BIN`` names a prebuilt binary instead.

Example (``points`` (n, 3), ``counts`` and ``indices`` as in USD)::

    from peers import osd_peer
    if osd_peer.available():
        out = osd_peer.refine(points, counts, indices, 2, scheme="catmark", boundary="edge-and-corner",
                              creases=[[0, 1]], crease_sharpness=[10.0], limit=True)
        out.levels[2].points, out.levels[2].faces(), out.limit_points, out.limit_normals()

``refine`` runs one mesh; ``refine_many`` runs several in one process (one start-up); ``bench`` returns the
benchmark's JSON as a dict. Option values (strings) map onto ``Sdc::Options``:

=============== ==========================================================================================
scheme          "catmark" (also "catmull-clark"), "loop", "bilinear"
boundary        VtxBoundaryInterpolation: "none", "edge-only", "edge-and-corner"
creasing        CreasingMethod: "uniform", "chaikin"
fvar_linear     FVarLinearInterpolation: "none", "corners-only", "corners-plus1", "corners-plus2",
                "boundaries", "all"
triangle_sub    TriangleSubdivision: "catmark", "smooth"
=============== ==========================================================================================
"""
from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import tempfile
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(HERE, "osd", "osd_peer.cpp")
BUILD_SCRIPT = os.path.join(HERE, "osd", "build.sh")
DEFAULT_BINARY = os.path.join(HERE, "osd", "build", "osd_peer")
OSD_HEADER = "/usr/include/opensubdiv/far/topologyRefiner.h"
MAGIC = b"OSDPEER1"

SCHEMES = {"bilinear": 0, "catmark": 1, "catmull-clark": 1, "loop": 2}
BOUNDARIES = {"none": 0, "edge-only": 1, "edge-and-corner": 2}
CREASING = {"uniform": 0, "chaikin": 1}
FVAR_LINEAR = {"none": 0, "corners-only": 1, "corners-plus1": 2, "corners-plus2": 3, "boundaries": 4, "all": 5}
TRIANGLE_SUB = {"catmark": 0, "smooth": 1}

#: Sdc::Crease::Rule bits in ``PeerLevel.vertex_rules``
RULE_SMOOTH, RULE_DART, RULE_CREASE, RULE_CORNER = 1, 2, 4, 8


class PeerError(RuntimeError):
    """osd_peer failed (OpenSubdiv refused the input, or the program could not run); carries its stderr."""


# ------------------------------------------------------------------------------------------ the binary
_state: dict = {}


def osd_installed() -> bool:
    """Whether OpenSubdiv's headers (libosd-dev) are present, so the program can be built."""
    return os.path.isfile(OSD_HEADER)


def _stale(binary: str) -> bool:
    return not os.path.isfile(binary) or os.path.getmtime(binary) < os.path.getmtime(SOURCE)


def binary(build: bool = True) -> Optional[str]:
    """Path of a runnable osd_peer, building it first when needed and possible; None when there is none.

    A build failure is remembered (``build_log()``) and not retried in the same process.
    """
    env = os.environ.get("OSD_PEER_BIN")
    if env:
        return env if os.access(env, os.X_OK) else None
    built = os.access(DEFAULT_BINARY, os.X_OK)
    if built and not _stale(DEFAULT_BINARY):
        return DEFAULT_BINARY
    can_build = build and osd_installed() and shutil.which(os.environ.get("CXX", "g++")) is not None
    if not can_build or "build_error" in _state:
        return DEFAULT_BINARY if built else None  # an older binary is better than none
    proc = subprocess.run(["bash", BUILD_SCRIPT], capture_output=True, text=True)
    if proc.returncode != 0 or not os.access(DEFAULT_BINARY, os.X_OK):
        _state["build_error"] = proc.stdout + proc.stderr
        return None
    return DEFAULT_BINARY


def build_log() -> str:
    """The compiler's output of a failed build in this process ('' when none failed)."""
    return _state.get("build_error", "")


def available() -> bool:
    """Whether the peer can run here: a binary exists or can be built, and it answers ``version``."""
    if "available" not in _state:
        exe = binary()
        ok = False
        if exe:
            try:
                proc = subprocess.run([exe, "version"], capture_output=True, text=True, timeout=30)
                ok = proc.returncode == 0
                _state["version"] = proc.stdout.strip()
            except OSError:
                ok = False
        _state["available"] = ok
    return _state["available"]


def version() -> Optional[str]:
    """OpenSubdiv's version as the binary reports it ("3.5.0"), or None when unavailable."""
    return _state.get("version") if available() else None


# --------------------------------------------------------------------------------------- record files
def write_records(path: str, records: dict) -> None:
    """Write {name: array} as an OSDPEER1 record file (integers as int32, reals as float64)."""
    with open(path, "wb") as fh:
        fh.write(MAGIC)
        for name, value in records.items():
            arr = np.asarray(value)
            if arr.dtype.kind in "biu":
                code, arr = b"i", np.asarray(arr, dtype="<i4")
            elif arr.dtype.kind == "f":
                code, arr = b"f", np.asarray(arr, dtype="<f8")
            else:
                raise TypeError(f"record {name}: unsupported dtype {arr.dtype}")
            key = name.encode("ascii")
            fh.write(struct.pack("<I", len(key)) + key + code + struct.pack("<I", arr.ndim))
            fh.write(struct.pack(f"<{arr.ndim}q", *arr.shape))
            fh.write(arr.tobytes(order="C"))


def read_records(path: str) -> dict:
    """Read an OSDPEER1 record file into {name: numpy array} (0-d records as numpy scalars' arrays)."""
    with open(path, "rb") as fh:
        data = fh.read()
    if data[:8] != MAGIC:
        raise PeerError(f"{path}: not an OSDPEER1 record file")
    out, pos = {}, 8
    while pos < len(data):
        (n,) = struct.unpack_from("<I", data, pos)
        name = data[pos + 4:pos + 4 + n].decode("ascii")
        pos += 4 + n
        code = data[pos:pos + 1]
        (ndim,) = struct.unpack_from("<I", data, pos + 1)
        shape = struct.unpack_from(f"<{ndim}q", data, pos + 5)
        pos += 5 + 8 * ndim
        dtype = np.dtype("<i4") if code == b"i" else np.dtype("<f8")
        count = int(np.prod(shape, dtype=np.int64))
        out[name] = np.frombuffer(data, dtype=dtype, count=count, offset=pos).reshape(shape).copy()
        pos += count * dtype.itemsize
    return out


# ----------------------------------------------------------------------------------------- results
@dataclass
class PeerLevel:
    """One level of OpenSubdiv's uniform refinement, hole faces included (flagged in ``face_holes``)."""

    points: np.ndarray
    face_counts: np.ndarray
    face_indices: np.ndarray
    face_holes: np.ndarray
    vertex_rules: np.ndarray
    vertex_boundary: np.ndarray
    vertex_nonmanifold: np.ndarray
    vertex_sharpness: np.ndarray
    edge_vertices: np.ndarray  # (E, 2)
    edge_sharpness: np.ndarray
    fvar_values: Optional[np.ndarray] = None
    fvar_indices: Optional[np.ndarray] = None

    def __repr__(self) -> str:  # short: test reports print their arguments
        return (f"PeerLevel({len(self.points)} vertices, {len(self.face_counts)} faces, "
                f"{int(np.count_nonzero(self.face_holes))} holes)")

    def faces(self, drop_holes: bool = True):
        """(counts, indices) int32, hole faces left out unless ``drop_holes=False``."""
        if not drop_holes:
            return self.face_counts, self.face_indices
        keep = self.face_holes == 0
        return self.face_counts[keep], self.face_indices[np.repeat(keep, self.face_counts)]

    def sharp_edge_counts(self, semi_sharp: bool = True) -> np.ndarray:
        """Sharp edges at each vertex: sharpness > 0 (what OpenSubdiv's vertex rules count), or with
        ``semi_sharp=False`` only infinitely sharp ones (>= 10); boundary edges included."""
        sharp = self.edge_sharpness > 0 if semi_sharp else self.edge_sharpness >= 10.0
        return np.bincount(self.edge_vertices[sharp].reshape(-1), minlength=len(self.points))

    def single_sector(self) -> np.ndarray:
        """Vertices with one sector (the faces between consecutive sharp edges), where ``T1 x T2`` is the
        surface normal: manifold interior vertices with at most one sharp edge and no corner rule, and manifold
        boundary vertices whose only sharp edges are their two boundary edges (corners included)."""
        s = self.sharp_edge_counts()
        interior = (self.vertex_boundary == 0) & (s <= 1) & (self.vertex_rules != RULE_CORNER)
        boundary = (self.vertex_boundary == 1) & (s == 2)
        return (interior | boundary) & (self.vertex_nonmanifold == 0)


@dataclass
class PeerResult:
    """``levels[0..N]``, and with ``limit=True`` the limit positions and first derivatives of level N."""

    levels: list
    limit_points: Optional[np.ndarray] = None
    limit_tan1: Optional[np.ndarray] = None
    limit_tan2: Optional[np.ndarray] = None
    records: dict = field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        return f"PeerResult(levels 0..{len(self.levels) - 1}, {self.last!r}, limit={self.limit_points is not None})"

    @property
    def last(self) -> PeerLevel:
        return self.levels[-1]

    def limit_normals(self) -> np.ndarray:
        """Unit T1 x T2 of level N's vertices (zero rows where OpenSubdiv gives no tangents)."""
        n = np.cross(self.limit_tan1, self.limit_tan2)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _result(rec: dict) -> PeerResult:
    levels = []
    for lvl in range(int(rec["num_levels"])):
        p = f"L{lvl}/"
        levels.append(PeerLevel(
            points=rec[p + "points"], face_counts=rec[p + "face_counts"], face_indices=rec[p + "face_indices"],
            face_holes=rec[p + "face_holes"], vertex_rules=rec[p + "vertex_rules"],
            vertex_boundary=rec[p + "vertex_boundary"], vertex_nonmanifold=rec[p + "vertex_nonmanifold"],
            vertex_sharpness=rec[p + "vertex_sharpness"], edge_vertices=rec[p + "edge_vertices"],
            edge_sharpness=rec[p + "edge_sharpness"], fvar_values=rec.get(p + "fvar_values"),
            fvar_indices=rec.get(p + "fvar_indices"),
        ))
    return PeerResult(levels, rec.get("limit/points"), rec.get("limit/tan1"), rec.get("limit/tan2"), rec)


# ------------------------------------------------------------------------------------------ requests
def _choice(table: dict, value: str, name: str) -> int:
    key = str(value).lower()
    if key not in table:
        raise ValueError(f"{name} must be one of {sorted(table)}, got {value!r}")
    return table[key]


def request(points, face_counts, face_indices, level: int, *, scheme: str = "catmark",
            boundary: str = "edge-and-corner", creasing: str = "uniform", fvar_linear: str = "all",
            triangle_sub: str = "catmark", creases=None, crease_sharpness=None, corners=None,
            corner_sharpness=None, holes=None, fvar=None, limit: bool = False, left_handed: bool = False) -> dict:
    """The input records of one mesh. ``points`` (n, d) any width; ``creases`` (m, 2) vertex pairs with
    ``crease_sharpness`` (default 10, infinitely sharp); ``corners`` with ``corner_sharpness`` likewise;
    ``holes`` face ids; ``fvar`` a pair (values (k, e), one value id per face-vertex)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 1:
        pts = pts[:, None]
    rec = {
        "points": pts,
        "face_counts": np.asarray(face_counts, dtype=np.int32).reshape(-1),
        "face_indices": np.asarray(face_indices, dtype=np.int32).reshape(-1),
        "scheme": np.int32(_choice(SCHEMES, scheme, "scheme")),
        "vtx_boundary": np.int32(_choice(BOUNDARIES, boundary, "boundary")),
        "creasing": np.int32(_choice(CREASING, creasing, "creasing")),
        "fvar_linear": np.int32(_choice(FVAR_LINEAR, fvar_linear, "fvar_linear")),
        "triangle_sub": np.int32(_choice(TRIANGLE_SUB, triangle_sub, "triangle_sub")),
        "left_handed": np.int32(bool(left_handed)),
        "level": np.int32(level),
        "limit": np.int32(bool(limit)),
    }
    if creases is not None and len(creases):
        pairs = np.asarray(creases, dtype=np.int32).reshape(-1, 2)
        sharp = np.broadcast_to(np.asarray(10.0 if crease_sharpness is None else crease_sharpness, float),
                                (len(pairs),))
        rec["crease_pairs"], rec["crease_sharpness"] = pairs, np.array(sharp, dtype=np.float64)
    if corners is not None and len(corners):
        ids = np.asarray(corners, dtype=np.int32).reshape(-1)
        sharp = np.broadcast_to(np.asarray(10.0 if corner_sharpness is None else corner_sharpness, float),
                                (len(ids),))
        rec["corner_vertices"], rec["corner_sharpness"] = ids, np.array(sharp, dtype=np.float64)
    if holes is not None and len(holes):
        rec["holes"] = np.asarray(holes, dtype=np.int32).reshape(-1)
    if fvar is not None:
        values, ids = fvar
        values = np.asarray(values, dtype=np.float64)
        rec["fvar_values"] = values[:, None] if values.ndim == 1 else values
        rec["fvar_indices"] = np.asarray(ids, dtype=np.int32).reshape(-1)
    return rec


def mesh_request(mesh, level: int, **options) -> dict:
    """``request`` for a ``warp_subdiv.Mesh`` (its creases, corners, sharpness and holes); keyword options
    as in :func:`request`."""
    return request(
        mesh.points, mesh.face_vertex_counts, mesh.face_vertex_indices, level,
        creases=mesh.creases, crease_sharpness=mesh.crease_sharpness, corners=mesh.corners,
        corner_sharpness=mesh.corner_sharpness, holes=mesh.holes, **options,
    )


def _run(args: Sequence[str], timeout: float) -> subprocess.CompletedProcess:
    exe = binary()
    if exe is None:
        raise PeerError("osd_peer is not available (install libosd-dev: peers/install_osd.sh)\n" + build_log())
    proc = subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise PeerError(f"osd_peer {args[0]} failed with exit status {proc.returncode}:\n{proc.stderr.strip()}")
    return proc


def refine_many(requests: Sequence[dict], timeout: float = 600) -> list:
    """Run several ``request`` dicts in one osd_peer process; one :class:`PeerResult` each, in order."""
    if not requests:
        return []
    with tempfile.TemporaryDirectory(prefix="osd_peer_") as tmp:
        args = ["refine"]
        for i, rec in enumerate(requests):
            src, dst = os.path.join(tmp, f"in{i}.osdp"), os.path.join(tmp, f"out{i}.osdp")
            write_records(src, rec)
            args += [src, dst]
        _run(args, timeout)
        return [_result(read_records(os.path.join(tmp, f"out{i}.osdp"))) for i in range(len(requests))]


def refine(points, face_counts, face_indices, level: int, **options) -> PeerResult:
    """OpenSubdiv's uniform refinement of one mesh to ``level`` (float64); options as in :func:`request`."""
    return refine_many([request(points, face_counts, face_indices, level, **options)])[0]


def bench(points, face_counts, face_indices, level: int, *, reps: int = 5, budget_mb: float = 2048,
          factorized: str = "last", timeout: float = 600, **options) -> dict:
    """Time OpenSubdiv on one mesh (see osd_peer.cpp's header for the phases); returns the JSON as a dict."""
    with tempfile.TemporaryDirectory(prefix="osd_peer_") as tmp:
        src = os.path.join(tmp, "mesh.osdp")
        write_records(src, request(points, face_counts, face_indices, level, **options))
        proc = _run(["bench", src, "--level", str(level), "--reps", str(reps), "--budget-mb", str(budget_mb),
                     "--factorized", factorized], timeout)
    return json.loads(proc.stdout)


# ------------------------------------------------------------------------------------------ Bfr (bfr_peer)
# A second program, peers/osd/bfr_peer.cpp (built by `peers/osd/build.sh bfr_peer` into peers/osd/build/bfr_peer, or
# named by BFR_PEER_BIN), drives OpenSubdiv's Bfr: RefinerSurfaceFactory, Surface::Evaluate and Tessellation.
# Its header documents the records; the mesh part of a request is the same as for osd_peer (``request``).

BFR_SOURCE = os.path.join(HERE, "osd", "bfr_peer.cpp")
BFR_DEFAULT_BINARY = os.path.join(HERE, "osd", "build", "bfr_peer")
BFR_HEADER = "/usr/include/opensubdiv/bfr/surface.h"


def bfr_binary(build: bool = True) -> Optional[str]:
    """Path of a runnable bfr_peer, built first when missing or older than its sources and OpenSubdiv's Bfr
    headers are installed; None when there is none (a failed build is remembered: ``bfr_build_log()``)."""
    env = os.environ.get("BFR_PEER_BIN")
    if env:
        return env if os.access(env, os.X_OK) else None
    exe = BFR_DEFAULT_BINARY
    built = os.access(exe, os.X_OK)
    stale = not built or any(os.path.getmtime(exe) < os.path.getmtime(src) for src in (BFR_SOURCE, SOURCE))
    if built and not stale:
        return exe
    can_build = build and os.path.isfile(BFR_HEADER) and shutil.which(os.environ.get("CXX", "g++")) is not None
    if not can_build or "bfr_build_error" in _state:
        return exe if built else None
    proc = subprocess.run(["bash", BUILD_SCRIPT, "bfr_peer"], capture_output=True, text=True)
    if proc.returncode != 0 or not os.access(exe, os.X_OK):
        _state["bfr_build_error"] = proc.stdout + proc.stderr
        return None
    return exe


def bfr_build_log() -> str:
    """The compiler's output of a failed bfr_peer build in this process ('' when none failed)."""
    return _state.get("bfr_build_error", "")


def bfr_available() -> bool:
    """Whether bfr_peer can run here (a binary exists or can be built, and it answers ``version``)."""
    if "bfr_available" not in _state:
        exe = bfr_binary()
        ok = False
        if exe:
            try:
                ok = subprocess.run([exe, "version"], capture_output=True, text=True, timeout=30).returncode == 0
            except OSError:
                ok = False
        _state["bfr_available"] = ok
    return _state["bfr_available"]


def _run_bfr(args: Sequence[str], timeout: float) -> subprocess.CompletedProcess:
    exe = bfr_binary()
    if exe is None:
        raise PeerError("bfr_peer is not available (install libosd-dev 3.5+: peers/install_osd.sh)\n"
                        + bfr_build_log())
    proc = subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise PeerError(f"bfr_peer {args[0]} failed with exit status {proc.returncode}:\n{proc.stderr.strip()}")
    return proc


def _bfr_records(rec: dict, approx_smooth: Optional[int], approx_sharp: Optional[int]) -> dict:
    rec = dict(rec)
    if approx_smooth is not None:
        rec["approx_smooth"] = np.int32(approx_smooth)
    if approx_sharp is not None:
        rec["approx_sharp"] = np.int32(approx_sharp)
    return rec


def bfr_evaluate(rec: dict, faces, uv, *, approx_smooth: Optional[int] = None, approx_sharp: Optional[int] = None,
                 timeout: float = 600) -> dict:
    """Bfr's limit surface at (face, u, v): ``rec`` a mesh ``request`` (or ``mesh_request``; its level and limit
    are ignored), ``faces`` (n,), ``uv`` (n, 2). Returns the output records (points, du, dv, duu, duv, dvv,
    valid, face_regular, face_vertex_uv, face_center_uv, face_subfaces) as numpy arrays."""
    rec = _bfr_records(rec, approx_smooth, approx_sharp)
    rec["query_faces"] = np.asarray(faces, dtype=np.int32).reshape(-1)
    rec["query_uv"] = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    with tempfile.TemporaryDirectory(prefix="bfr_peer_") as tmp:
        src, dst = os.path.join(tmp, "in.osdp"), os.path.join(tmp, "out.osdp")
        write_records(src, rec)
        _run_bfr(["evaluate", src, dst], timeout)
        return read_records(dst)


def bfr_tessellate(rec: dict, rates, *, edge_rates=None, preserve_quads: bool = True,
                   approx_smooth: Optional[int] = None, approx_sharp: Optional[int] = None,
                   timeout: float = 600) -> dict:
    """Bfr::Tessellation of every face (``rates`` one per face; ``edge_rates`` optionally one per face edge) and
    the surface at its coordinates: records coord_offsets, coords, points, facet_offsets, facets."""
    rec = _bfr_records(rec, approx_smooth, approx_sharp)
    rec["rates"] = np.asarray(rates, dtype=np.int32).reshape(-1)
    if edge_rates is not None:
        rec["edge_rates"] = np.asarray(edge_rates, dtype=np.int32).reshape(-1)
    rec["preserve_quads"] = np.int32(bool(preserve_quads))
    with tempfile.TemporaryDirectory(prefix="bfr_peer_") as tmp:
        src, dst = os.path.join(tmp, "in.osdp"), os.path.join(tmp, "out.osdp")
        write_records(src, rec)
        _run_bfr(["tessellate", src, dst], timeout)
        return read_records(dst)


def bfr_bench(rec: dict, faces, uv, *, reps: int = 3, approx_smooth: Optional[int] = None,
              approx_sharp: Optional[int] = None, timeout: float = 600) -> dict:
    """Time Bfr on the query points (see bfr_peer.cpp's header); returns the JSON as a dict."""
    rec = _bfr_records(rec, approx_smooth, approx_sharp)
    rec["query_faces"] = np.asarray(faces, dtype=np.int32).reshape(-1)
    rec["query_uv"] = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    with tempfile.TemporaryDirectory(prefix="bfr_peer_") as tmp:
        src = os.path.join(tmp, "in.osdp")
        write_records(src, rec)
        proc = _run_bfr(["bench", src, "--reps", str(reps)], timeout)
    return json.loads(proc.stdout)
