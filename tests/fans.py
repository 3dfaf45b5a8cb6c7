"""One-ring test patches and the local subdivision matrix read off the implementation itself."""
import numpy as np

import warp_subdiv as ws
from warp_subdiv.tables.projections import ring_local_vectors, sector_local_vectors
from warp_subdiv.topology import base_level, refine_level

SCHEME_FACES = {"catmull-clark": 4, "loop": 3}


def _one_ring(scheme, k, kind, alpha, twist):
    """Faces around vertex 0: a closed ring of valence k, or a sector of k faces spanning its angle."""
    interior = kind == "interior"
    nring = k if interior else k + 1
    span = {"interior": 2 * np.pi, "crease": np.pi, "convex": alpha, "concave": 2 * np.pi - alpha}[kind]
    if kind == "crease" and k == 1:
        span = np.pi / 2  # one face cannot span a straight angle
    step = span / k
    ang = np.arange(nring) * step
    p = np.stack([np.cos(ang), np.sin(ang), twist * (-1.0) ** np.arange(nring)], axis=1)
    pts = [np.zeros(3)] + list(p)
    faces = []
    for i in range(k):
        a, b = 1 + i, 1 + (i + 1) % nring
        if scheme == "catmull-clark":
            mid = ang[i] + step / 2
            pts.append([1.4 * np.cos(mid), 1.4 * np.sin(mid), 0.0])
            faces.append([0, a, len(pts) - 1, b])
        else:
            faces.append([0, a, b])
    return np.array(pts), np.array(faces)


def patch(scheme, k, kind="interior", alpha=np.pi / 2, twist=0.0):
    """A patch whose vertex 0 has the requested neighbourhood and whose ring vertices are all untagged.

    The one-ring is refined once (its ring points become interior edge children), and the result is the
    control mesh. kind: "interior" (valence k), "crease" (a boundary sector of k faces), "convex"/"concave"
    (a corner sector of k faces whose crease edges meet at angle alpha; concave spans 2 pi - alpha)."""
    pts, faces = _one_ring(scheme, k, kind, alpha, twist)
    ring = ws.Mesh(pts, [len(f) for f in faces], faces.reshape(-1),
                   corners=[0] if kind in ("convex", "concave") else None)  # keep alpha on refinement
    fine = ws.refine(ring, 1, scheme=scheme, rules="opensubdiv", device="cpu", precision="float64")
    corners = concave = None
    if kind in ("convex", "concave"):
        corners = [0]
    mesh = ws.Mesh(fine.points, fine.face_vertex_counts, fine.face_vertex_indices, corners=corners)
    if kind == "concave":
        level = base_level(mesh, scheme, "edge-and-corner", "piecewise-smooth")
        inner = [int(e) for e in range(level.num_edges) if 0 in level.edge_verts[e] and not level.edge_sharp[e]]
        other = int(level.edge_verts[inner[0]].sum())
        concave = [[0, other]]
        mesh = ws.Mesh(fine.points, fine.face_vertex_counts, fine.face_vertex_indices, corners=corners,
                       concave=concave)
    return mesh


def local_ids(scheme, mesh, kind, k, levels=1, **options):
    """Vertex ids of vertex 0's local vector at level 0 .. levels (docs/rules.md section 0 order)."""
    rule_set = options.get("rules", "piecewise-smooth")
    level = base_level(mesh, scheme, options.get("boundary", "edge-and-corner"), rule_set)
    out = []
    for _ in range(levels + 1):
        if kind == "interior":
            out.append(ring_local_vectors(level, np.array([0]), k)[0])
        else:
            sector = int(np.flatnonzero(level.sector_vertex == 0)[0])
            out.append(sector_local_vectors(level, np.array([sector]), k)[0])
        level = refine_level(level)
    return out


def options_for(kind, k):
    """A one-face boundary vertex is a corner under edge-and-corner: a k = 1 crease needs edge-only."""
    return {"boundary": "edge-only"} if kind == "crease" and k == 1 else {}


def local_matrix(scheme, mesh, kind, k, **options):
    """S with (level-1 local vector) = S (level-0 local vector), read off Refiner.evaluate of unit vectors."""
    options.setdefault("device", "cpu")
    for key, value in options_for(kind, k).items():
        options.setdefault(key, value)
    r = ws.Refiner(mesh, 1, scheme=scheme, precision="float64", **options)
    out = r.evaluate(np.eye(mesh.num_vertices), normal_control=False)
    ids0, ids1 = local_ids(scheme, mesh, kind, k, **{k_: v for k_, v in options.items() if k_ != "device"})
    return out[np.ix_(ids1, ids0)]


def only_at_centre(mesh, s):
    """A per-vertex flatness array: s at vertex 0, 0 elsewhere."""
    arr = np.zeros(mesh.num_vertices)
    arr[0] = s
    return arr
