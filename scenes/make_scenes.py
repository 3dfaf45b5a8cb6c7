"""Writes the bundled USD scenes (the figures of Biermann, Levin and Zorin 2000) and, with --previews, their
rendered previews in docs/.

    python scenes/make_scenes.py              # rewrite scenes/*.usda
    python scenes/make_scenes.py --previews   # also refine each scene and render docs/<scene>.png

Every scene is built from plain Python data (:data:`SCENES`), which the tests use to build the same meshes
without USD. Piecewise-smooth and OpenSubdiv variants sit side by side (an Xform each, translated along x)
wherever the paper compares rules.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


@dataclass
class MeshSpec:
    """One mesh of a scene: control mesh, USD subdivision attributes and warp-subdiv's subdiv: tags."""

    name: str  # prim path relative to /World, e.g. "PiecewiseSmooth/Plate"
    points: np.ndarray
    counts: list
    indices: list
    scheme: str = "catmullClark"
    rules: str | None = None  # subdiv:rules (None: not authored -> piecewise-smooth)
    creases: list = field(default_factory=list)  # polylines of vertex ids (infinitely sharp)
    corners: list = field(default_factory=list)
    concave: list = field(default_factory=list)  # (corner vertex, neighbour vertex)
    normals: dict = field(default_factory=dict)  # vertex id -> unit normal
    holes: list = field(default_factory=list)
    translate: tuple = (0.0, 0.0, 0.0)  # of the Xform that holds the mesh
    color: tuple = (0.7, 0.7, 0.7)
    time_points: dict = field(default_factory=dict)  # time -> points (animated meshes)
    primvars: bool = False  # author the demo primvars and a face subset (animated scene)

    def tags(self) -> dict:
        """The Mesh keyword arguments these tags amount to (for warp_subdiv.Mesh)."""
        pairs = [(a, b) for line in self.creases for a, b in zip(line[:-1], line[1:])]
        kw = {}
        if pairs:
            kw["creases"] = np.array(pairs)
        if self.corners:
            kw["corners"] = np.array(self.corners)
        if self.concave:
            kw["concave"] = np.array(self.concave)
        if self.normals:
            ids = sorted(self.normals)
            kw["normals"] = (np.array(ids), np.array([self.normals[i] for i in ids], dtype=np.float64))
        if self.holes:
            kw["holes"] = np.array(self.holes)
        return kw


@dataclass
class Scene:
    name: str
    title: str
    figure: str
    meshes: list
    view: tuple = (-60.0, 35.0)  # preview camera: azimuth, elevation (degrees)
    levels: int = 4  # preview levels
    time_range: tuple | None = None
    writer: object = None  # writes the scene itself (meshes then lists the meshes as they compose)


# -- geometry -------------------------------------------------------------------------------------------

class Builder:
    """Collects vertices by key and quads/triangles as vertex keys."""

    def __init__(self):
        self.ids: dict = {}
        self.points: list = []
        self.faces: list = []

    def v(self, key, pos) -> int:
        if key not in self.ids:
            self.ids[key] = len(self.points)
            self.points.append([float(c) for c in pos])
        return self.ids[key]

    def face(self, *ids):
        self.faces.append(list(ids))

    def arrays(self):
        return (np.array(self.points, dtype=np.float64), [len(f) for f in self.faces],
                [i for f in self.faces for i in f])


def lifted_grid(cells, step, height):
    """Quads over the unit cells (i, j) of a grid (counter-clockwise seen from +z); z = height(i, j)."""
    b = Builder()
    for i, j in cells:
        ids = [b.v((a, c), (a * step, c * step, height(a, c)))
               for a, c in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))]
        b.face(*ids)
    return b


def interior_neighbour(b: Builder, vertex: int) -> int:
    """A neighbour of ``vertex`` across an edge with two faces (for concave tags, which name such an edge)."""
    uses = {}
    for f in b.faces:
        for p, q in zip(f, f[1:] + f[:1]):
            uses[frozenset((p, q))] = uses.get(frozenset((p, q)), 0) + 1
    return min(next(iter(e - {vertex})) for e, n in uses.items() if vertex in e and n == 2)


def concave_corner_meshes():
    """Fig. 2 and 11: an L-shaped plate and a plate with a square hole, concave corners tagged."""
    out = []
    # L-shaped plate: 4x4 cells minus the 2x2 block at the top right; interior lifted into a dome
    cells = [(i, j) for i in range(4) for j in range(4) if not (i >= 2 and j >= 2)]
    b = lifted_grid(cells, 0.5, lambda a, c: 0.0 if a in (0, 4) or c in (0, 4) or (a >= 2 and c >= 2) else
                    0.35 * math.sin(math.pi * a / 4) * math.sin(math.pi * c / 4) + 0.1)
    corner = b.ids[(2, 2)]
    inner = interior_neighbour(b, corner)
    pts, counts, idx = b.arrays()
    pts[corner, 2] += 0.4
    # a plate with a square hole: 5x5 cells minus the centre, the four hole corners concave
    cells2 = [(i, j) for i in range(5) for j in range(5) if (i, j) != (2, 2)]
    b2 = lifted_grid(cells2, 0.4, lambda a, c: 0.3 * math.sin(math.pi * a / 5) * math.sin(math.pi * c / 5))
    hole_corners = [b2.ids[k] for k in ((2, 2), (3, 2), (3, 3), (2, 3))]
    hole_inner = [interior_neighbour(b2, c) for c in hole_corners]
    pts2, counts2, idx2 = b2.arrays()
    pts2[hole_corners, 2] += 0.3
    pts2 = pts2 + [0.0, -2.6, 0.0]
    for variant, rules, x, color in (("PiecewiseSmooth", "piecewise-smooth", 0.0, (0.85, 0.55, 0.35)),
                                     ("OpenSubdiv", "opensubdiv", 2.6, (0.45, 0.6, 0.85))):
        out.append(MeshSpec(f"{variant}/LPlate", pts, counts, idx, rules=rules, corners=[corner],
                            concave=[(corner, inner)] if rules == "piecewise-smooth" else [], translate=(x, 0, 0),
                            color=color))
        out.append(MeshSpec(f"{variant}/HoledPlate", pts2, counts2, idx2, rules=rules, corners=hole_corners,
                            concave=list(zip(hole_corners, hole_inner)) if rules == "piecewise-smooth" else [],
                            translate=(x, 0, 0), color=color))
    return out


def half_fan(k, radius=1.0, lift=lambda ang, r: 0.0):
    """k quads around boundary vertex 0 at the origin, spanning angles 0..pi (a half disk), plus a ring."""
    b = Builder()
    c = b.v("c", (0, 0, lift(0, 0)))
    ring = [b.v(("p", i), (radius * math.cos(math.pi * i / k), radius * math.sin(math.pi * i / k),
                          lift(math.pi * i / k, radius))) for i in range(k + 1)]
    mids = [b.v(("q", i), (1.35 * radius * math.cos(math.pi * (i + 0.5) / k),
                          1.35 * radius * math.sin(math.pi * (i + 0.5) / k),
                          lift(math.pi * (i + 0.5) / k, 1.35 * radius))) for i in range(k)]
    for i in range(k):
        b.face(c, ring[i], mids[i], ring[i + 1])
    return b


def shared_boundary_meshes():
    """Fig. 10a: two meshes with one boundary curve; the left has 3 faces at the middle boundary vertex
    (extraordinary), the right 2 (regular). With both rule sets the refined boundaries coincide: no gap."""
    out = []
    zb = 0.35  # the shared boundary bulges up in its middle
    # left: half fan of 3 quads at B = (0, 0), opening towards -x; boundary neighbours (0, +-1)
    left = Builder()
    bid = left.v("B", (0, 0, zb))
    ring = [left.v(("p", i), (-math.sin(math.pi * i / 3), math.cos(math.pi * i / 3), 0.0)) for i in range(4)]
    mids = [left.v(("q", i), (-1.35 * math.sin(math.pi * (i + 0.5) / 3), 1.35 * math.cos(math.pi * (i + 0.5) / 3),
                              0.15)) for i in range(3)]
    for i in range(3):
        left.face(bid, ring[i], mids[i], ring[i + 1])
    # right: a 2x2 grid x in [0, 1.6], y in [-1, 1] whose left column is the same three points
    right = Builder()
    for i in range(2):
        for j in range(2):
            def pos(a, c):
                x, y = 0.8 * a, -1.0 + c
                z = zb if (a, c) == (0, 1) else (0.15 if a == 1 and c == 1 else 0.0)
                return (x, y, z)
            ids = [right.v((a, c), pos(a, c)) for a, c in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))]
            right.face(*ids)
    lp, lc, li = left.arrays()
    rp, rc, ri = right.arrays()
    for variant, rules, y in (("PiecewiseSmooth", "piecewise-smooth", 0.0), ("OpenSubdiv", "opensubdiv", -2.8)):
        out.append(MeshSpec(f"{variant}/Left", lp, lc, li, rules=rules, translate=(0, y, 0), color=(0.85, 0.55, 0.35)))
        out.append(MeshSpec(f"{variant}/Right", rp, rc, ri, rules=rules, translate=(0, y, 0), color=(0.45, 0.6, 0.85)))
    return out


def twisted_boundary_meshes():
    """Fig. 3: an extraordinary boundary vertex (5 faces) whose boundary rises on one side and falls on the
    other while the interior stays level: a twist."""
    b = half_fan(5, 1.0, lambda ang, r: 0.45 * r * math.cos(ang) ** 3)
    pts, counts, idx = b.arrays()
    return [MeshSpec(f"{variant}/Fan", pts, counts, idx, rules=rules, translate=(x, 0, 0), color=color)
            for variant, rules, x, color in (("PiecewiseSmooth", "piecewise-smooth", 0.0, (0.85, 0.55, 0.35)),
                                             ("OpenSubdiv", "opensubdiv", 3.0, (0.45, 0.6, 0.85)))]


def complex_corner_meshes():
    """Fig. 12a: an L-shaped block; at its re-entrant top (and bottom) vertex two convex sectors (the walls)
    and one concave sector (the top, 270 degrees) meet."""
    cells = [(i, j) for i in range(4) for j in range(4) if not (i >= 2 and j >= 2)]
    b = Builder()
    edges = {}
    for i, j in cells:
        quad = ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))
        for p, q in zip(quad, quad[1:] + quad[:1]):
            edges[(p, q)] = edges.get((p, q), 0) + 1
    boundary = [(p, q) for (p, q) in edges if (q, p) not in edges]
    on_outline = {p for e in boundary for p in e}

    def z_top(a, c):
        return 1.0 if (a, c) in on_outline else 1.0 + 0.3 * math.sin(math.pi * a / 4) * math.sin(math.pi * c / 4) + 0.1

    for i, j in cells:
        quad = ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))
        b.face(*[b.v(("t", p), (0.5 * p[0], 0.5 * p[1], z_top(*p))) for p in quad])
        b.face(*[b.v(("b", p), (0.5 * p[0], 0.5 * p[1], 0.0)) for p in reversed(quad)])
    for p, q in boundary:  # walls: the top's boundary edge p->q, seen from outside
        b.face(b.v(("b", p), (0.5 * p[0], 0.5 * p[1], 0.0)), b.v(("b", q), (0.5 * q[0], 0.5 * q[1], 0.0)),
               b.v(("t", q), None), b.v(("t", p), None))
    # outline as a closed loop, and its turning points (where vertical crease edges run)
    nxt = {p: q for p, q in boundary}
    loop = [boundary[0][0]]
    while nxt[loop[-1]] != loop[0]:
        loop.append(nxt[loop[-1]])
    turns = [p for k, p in enumerate(loop)
             if (p[0] - loop[k - 1][0], p[1] - loop[k - 1][1]) != (nxt[p][0] - p[0], nxt[p][1] - p[1])]
    creases = [[b.ids[("t", p)] for p in loop + loop[:1]], [b.ids[("b", p)] for p in loop + loop[:1]]]
    creases += [[b.ids[("b", p)], b.ids[("t", p)]] for p in turns]
    reentrant = (2, 2)
    concave = [(b.ids[(side, reentrant)], interior_neighbour(b, b.ids[(side, reentrant)])) for side in "tb"]
    pts, counts, idx = b.arrays()
    return [MeshSpec(f"{variant}/Block", pts, counts, idx, rules=rules, creases=creases,
                     concave=concave if rules == "piecewise-smooth" else [], translate=(x, 0, 0), color=color)
            for variant, rules, x, color in (("PiecewiseSmooth", "piecewise-smooth", 0.0, (0.85, 0.55, 0.35)),
                                             ("OpenSubdiv", "opensubdiv", 2.8, (0.45, 0.6, 0.85)))]


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return tuple(float(c) for c in v / np.linalg.norm(v))


def plane_normals_meshes():
    """Fig. 12b: a plane with a prescribed normal at an interior and at a boundary vertex (left), and the same
    plane without (right)."""
    b = lifted_grid([(i, j) for i in range(6) for j in range(6)], 0.4, lambda a, c: 0.0)
    pts, counts, idx = b.arrays()
    normals = {b.ids[(2, 3)]: _unit((0.6, 0.0, 0.8)), b.ids[(6, 3)]: _unit((0.0, 0.6, 0.8))}
    return [MeshSpec("Normals/Plane", pts, counts, idx, normals=normals, color=(0.85, 0.55, 0.35)),
            MeshSpec("Plain/Plane", pts, counts, idx, translate=(3.0, 0, 0), color=(0.6, 0.6, 0.6))]


ICOSAHEDRON = np.array([(0, -1, -1.618034), (0, 1, -1.618034), (0, -1, 1.618034), (0, 1, 1.618034),
                        (-1, -1.618034, 0), (1, -1.618034, 0), (-1, 1.618034, 0), (1, 1.618034, 0),
                        (-1.618034, 0, -1), (1.618034, 0, -1), (-1.618034, 0, 1), (1.618034, 0, 1)]) / 1.902113
ICOSAHEDRON_FACES = [(0, 1, 9), (0, 8, 1), (0, 9, 5), (0, 5, 4), (0, 4, 8), (1, 8, 6), (1, 6, 7), (1, 7, 9),
                     (2, 3, 10), (2, 11, 3), (2, 10, 4), (2, 4, 5), (2, 5, 11), (3, 11, 7), (3, 7, 6), (3, 6, 10),
                     (4, 10, 8), (5, 9, 11), (6, 8, 10), (7, 11, 9)]


def _outward_faces(points, faces):
    """Orient triangles so that their normals point away from the origin."""
    out = []
    for f in faces:
        a, b, c = (points[i] for i in f)
        out.append(f if np.dot(np.cross(b - a, c - a), a + b + c) > 0 else (f[0], f[2], f[1]))
    return out


def icosahedron_normals_meshes():
    """Fig. 13 (Loop): an icosahedron with every normal up, horizontal (radial), and down."""
    faces = _outward_faces(ICOSAHEDRON, ICOSAHEDRON_FACES)
    counts, idx = [3] * len(faces), [i for f in faces for i in f]
    horizontal = {i: _unit((p[0], p[1], 0.0)) for i, p in enumerate(ICOSAHEDRON)}
    variants = (("Up", {i: (0.0, 0.0, 1.0) for i in range(12)}, 0.0), ("Horizontal", horizontal, 2.6),
                ("Down", {i: (0.0, 0.0, -1.0) for i in range(12)}, 5.2))
    return [MeshSpec(f"{name}/Icosahedron", ICOSAHEDRON, counts, idx, scheme="loop", normals=n, translate=(x, 0, 0),
                     color=(0.45, 0.6, 0.85)) for name, n, x in variants]


CUBE = np.array([(x, y, z) for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=np.float64)
CUBE_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def cube_normals_meshes():
    """Fig. 14 (Catmull-Clark): a cube with every normal up, no normal control, and normals horizontal."""
    counts, idx = [4] * 6, [i for f in CUBE_FACES for i in f]
    horizontal = {i: _unit((p[0], p[1], 0.0)) for i, p in enumerate(CUBE)}
    variants = (("Up", {i: (0.0, 0.0, 1.0) for i in range(8)}, 0.0), ("Plain", {}, 2.0),
                ("Horizontal", horizontal, 4.0))
    return [MeshSpec(f"{name}/Cube", CUBE, counts, idx, normals=n, translate=(x, 0, 0), color=(0.85, 0.55, 0.35))
            for name, n, x in variants]


def animated_meshes():
    """An animated plate with a crease and a corner: time-sampled points and velocities (frames 1-24), vertex,
    varying, uniform and face-varying primvars (some indexed), and a face subset bound to a material."""
    b = lifted_grid([(i, j) for i in range(4) for j in range(3)], 0.5, lambda a, c: 0.0)
    pts, counts, idx = b.arrays()
    crease = [b.ids[(a, 1)] for a in range(5)]
    corner = b.ids[(0, 0)]
    frames = {}
    for t in range(1, 25):
        phase = 2 * math.pi * (t - 1) / 24
        p = pts.copy()
        p[:, 2] = 0.35 * np.sin(phase + 2.0 * p[:, 0]) * p[:, 1]
        frames[float(t)] = p
    return [MeshSpec("Animated/Plate", frames[1.0], counts, idx, creases=[crease], corners=[corner],
                     time_points=frames, primvars=True, color=(0.5, 0.75, 0.5))]


STUD = CUBE * [1.6, 1.6, 0.8]  # a flat box
STUD_CREASES = [[4, 5, 7, 6, 4], [0, 1, 3, 2, 0]]  # its top and bottom squares: closed creases when "creased"
STUDS = (("Stud_1", "soft"), ("Stud_2", "creased"), ("Stud_3", "soft"), ("Stud_4", "creased"))
PEBBLES = ((0.0, 0.55, 0.0), (1.5, 0.7, 40.0), (3.0, 0.5, 80.0), (4.5, 0.8, 120.0), (6.0, 0.6, 160.0))


def instanced_meshes():
    """Production structure: four instances of one asset (a Catmull-Clark box) whose variant set edges =
    soft | creased creases its top and bottom squares, and a PointInstancer scattering a Loop pebble (an instance of a
    second asset). The meshes as they compose (instance proxies), for the tests."""
    counts, idx = [4] * 6, [i for f in CUBE_FACES for i in f]
    out = [MeshSpec(f"{name}/Mesh", STUD, counts, idx, creases=STUD_CREASES if edges == "creased" else [],
                    color=(0.85, 0.55, 0.35)) for name, edges in STUDS]
    faces = _outward_faces(ICOSAHEDRON, ICOSAHEDRON_FACES)
    out.append(MeshSpec("Pebbles/Prototypes/Pebble/Mesh", ICOSAHEDRON, [3] * len(faces),
                        [i for f in faces for i in f], scheme="loop", color=(0.45, 0.6, 0.85)))
    return out


def write_instanced_scene(scene: "Scene", path: str) -> None:
    """The assets are classes (/Assets, not part of the scene) that the instances reference internally."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    layer.documentation = (f"warp-subdiv scene {scene.name}: {scene.title}. Written by scenes/make_scenes.py.")
    stage.CreateClassPrim("/Assets")

    def mesh_of(prim_path, spec):
        mesh = UsdGeom.Mesh.Define(stage, prim_path)
        mesh.CreateSubdivisionSchemeAttr(spec.scheme)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray(list(spec.counts)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(list(spec.indices)))
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(spec.points.astype(np.float32)))
        lo, hi = spec.points.min(0), spec.points.max(0)
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        mesh.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*spec.color)]))
        return mesh

    # the stud asset and its variant set
    soft = next(s for s in scene.meshes if not s.creases)
    stud = UsdGeom.Xform.Define(stage, "/Assets/Stud").GetPrim()
    mesh = mesh_of("/Assets/Stud/Mesh", soft)
    edges = stud.GetVariantSets().AddVariantSet("edges")
    for name in ("soft", "creased"):
        edges.AddVariant(name)
        edges.SetVariantSelection(name)
        if name == "creased":
            with edges.GetVariantEditContext():
                mesh.CreateCreaseIndicesAttr(Vt.IntArray([i for loop in STUD_CREASES for i in loop]))
                mesh.CreateCreaseLengthsAttr(Vt.IntArray([len(loop) for loop in STUD_CREASES]))
                mesh.CreateCreaseSharpnessesAttr(Vt.FloatArray([10.0] * len(STUD_CREASES)))
    edges.SetVariantSelection("soft")
    # the pebble asset
    UsdGeom.Xform.Define(stage, "/Assets/Pebble")
    mesh_of("/Assets/Pebble/Mesh", scene.meshes[-1])
    # four stud instances, two variants
    for i, (name, variant) in enumerate(STUDS):
        prim = UsdGeom.Xform.Define(stage, f"/World/{name}")
        prim.AddTranslateOp().Set(Gf.Vec3d(2.5 * i, 0.0, 0.0))
        prim.GetPrim().GetReferences().AddInternalReference("/Assets/Stud")
        prim.GetPrim().SetInstanceable(True)
        prim.GetPrim().GetVariantSets().GetVariantSet("edges").SetVariantSelection(variant)
    # a PointInstancer scattering the pebble (its prototype an instance of the pebble asset)
    pebbles = UsdGeom.PointInstancer.Define(stage, "/World/Pebbles")
    UsdGeom.Scope.Define(stage, "/World/Pebbles/Prototypes")
    proto = UsdGeom.Xform.Define(stage, "/World/Pebbles/Prototypes/Pebble").GetPrim()
    proto.GetReferences().AddInternalReference("/Assets/Pebble")
    proto.SetInstanceable(True)
    pebbles.CreatePrototypesRel().SetTargets([proto.GetPath()])
    pebbles.CreateProtoIndicesAttr(Vt.IntArray([0] * len(PEBBLES)))
    pebbles.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(x + 0.75, -2.2, 0.0) for x, _, _ in PEBBLES]))
    pebbles.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(s, s, s) for _, s, _ in PEBBLES]))
    pebbles.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(Gf.Rotation(Gf.Vec3d(0, 0, 1), a).GetQuat())
                                                  for _, _, a in PEBBLES]))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(layer.ExportToString())


SCENES = {s.name: s for s in (
    Scene("concave_corner", "Concave corners: an L-shaped plate and a plate with a hole", "Fig. 2, 11",
          concave_corner_meshes(), view=(-135.0, 35.0)),
    Scene("shared_boundary", "Two meshes sharing a boundary: no gap with either rule set", "Fig. 10a",
          shared_boundary_meshes(), view=(-150.0, 40.0)),
    Scene("twisted_boundary", "A twisted extraordinary boundary vertex", "Fig. 3",
          twisted_boundary_meshes(), view=(-100.0, 30.0)),
    Scene("complex_corner", "A complex corner: two convex sectors and a concave one", "Fig. 12a",
          complex_corner_meshes(), view=(-130.0, 40.0)),
    Scene("plane_normals", "A plane with an interior and a boundary normal prescribed", "Fig. 12b",
          plane_normals_meshes(), view=(-100.0, 40.0)),
    Scene("icosahedron_normals", "Loop icosahedra: normals up, horizontal, down", "Fig. 13",
          icosahedron_normals_meshes(), view=(-90.0, 15.0)),
    Scene("cube_normals", "Catmull-Clark cubes: normals up, none, horizontal", "Fig. 14",
          cube_normals_meshes(), view=(-90.0, 20.0)),
    Scene("animated", "An animated creased plate with primvars and a material subset", "-",
          animated_meshes(), view=(-70.0, 35.0), levels=3, time_range=(1.0, 24.0)),
    Scene("instanced", "Instances of a box asset with a crease variant (soft, creased) and point-instanced "
          "Loop pebbles", "-", instanced_meshes(), view=(-62.0, 38.0), levels=3, writer=write_instanced_scene),
)}


# -- USD ------------------------------------------------------------------------------------------------

def write_scene(scene: Scene, path: str) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    if scene.writer is not None:
        scene.writer(scene, path)
        return

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    layer.documentation = (f"warp-subdiv scene {scene.name}: {scene.title} ({scene.figure}). "
                           "Written by scenes/make_scenes.py.")
    if scene.time_range:
        stage.SetStartTimeCode(scene.time_range[0])
        stage.SetEndTimeCode(scene.time_range[1])
        stage.SetTimeCodesPerSecond(24)
    for spec in scene.meshes:
        group_name, mesh_name = spec.name.split("/")
        group = UsdGeom.Xform.Define(stage, f"/World/{group_name}")
        if any(spec.translate) and not group.GetOrderedXformOps():
            group.AddTranslateOp().Set(Gf.Vec3d(*spec.translate))
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{group_name}/{mesh_name}")
        mesh.CreateSubdivisionSchemeAttr(spec.scheme)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray(list(spec.counts)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(list(spec.indices)))
        pts_attr = mesh.CreatePointsAttr()
        if spec.time_points:
            for t, p in spec.time_points.items():
                pts_attr.Set(Vt.Vec3fArray.FromNumpy(p.astype(np.float32)), t)
            times = sorted(spec.time_points)
            vel = mesh.CreateVelocitiesAttr()
            for k, t in enumerate(times):  # central differences, in units per second (24 fps)
                lo, hi = times[max(k - 1, 0)], times[min(k + 1, len(times) - 1)]
                v = (spec.time_points[hi] - spec.time_points[lo]) / (hi - lo) * 24.0
                vel.Set(Vt.Vec3fArray.FromNumpy(v.astype(np.float32)), t)
            allp = np.concatenate(list(spec.time_points.values()))
        else:
            pts_attr.Set(Vt.Vec3fArray.FromNumpy(spec.points.astype(np.float32)))
            allp = spec.points
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, allp.min(0))), Gf.Vec3f(*map(float, allp.max(0)))]))
        mesh.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*spec.color)]))
        pairs = [line for line in spec.creases]
        if pairs:
            mesh.CreateCreaseIndicesAttr(Vt.IntArray([i for line in pairs for i in line]))
            mesh.CreateCreaseLengthsAttr(Vt.IntArray([len(line) for line in pairs]))
            mesh.CreateCreaseSharpnessesAttr(Vt.FloatArray([10.0] * len(pairs)))
        if spec.corners:
            mesh.CreateCornerIndicesAttr(Vt.IntArray(spec.corners))
            mesh.CreateCornerSharpnessesAttr(Vt.FloatArray([10.0] * len(spec.corners)))
        if spec.holes:
            mesh.CreateHoleIndicesAttr(Vt.IntArray(spec.holes))
        prim = mesh.GetPrim()
        if spec.rules:
            prim.CreateAttribute("subdiv:rules", Sdf.ValueTypeNames.Token, custom=True).Set(spec.rules)
        if spec.concave:
            prim.CreateAttribute("subdiv:concave", Sdf.ValueTypeNames.Int2Array, custom=True).Set(
                Vt.Vec2iArray([Gf.Vec2i(int(a), int(b)) for a, b in spec.concave]))
        if spec.normals:
            ids = sorted(spec.normals)
            prim.CreateAttribute("subdiv:normalIndices", Sdf.ValueTypeNames.IntArray, custom=True).Set(
                Vt.IntArray(ids))
            prim.CreateAttribute("subdiv:normals", Sdf.ValueTypeNames.Normal3fArray, custom=True).Set(
                Vt.Vec3fArray([Gf.Vec3f(*spec.normals[i]) for i in ids]))
        if spec.primvars:
            _demo_primvars(stage, mesh, spec)
    text = layer.ExportToString()
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def _demo_primvars(stage, mesh, spec):
    """Primvars of every interpolation (the animated scene), a face subset and its material binding."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    api = UsdGeom.PrimvarsAPI(mesh)
    pts = spec.points
    nf = len(spec.counts)
    # vertex colour: x -> red, y -> green
    span = np.ptp(pts, axis=0) + 1e-9
    col = np.stack([(pts[:, 0] - pts[:, 0].min()) / span[0], (pts[:, 1] - pts[:, 1].min()) / span[1],
                    np.full(len(pts), 0.4)], axis=1)
    api.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex).Set(
        Vt.Vec3fArray.FromNumpy(col.astype(np.float32)))
    # varying weight, animated
    w = api.CreatePrimvar("weight", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.varying)
    for t in (1.0, 12.0, 24.0):
        w.Set(Vt.FloatArray.FromNumpy((np.linspace(0, 1, len(pts)) * t / 24).astype(np.float32)), t)
    # face-varying st, indexed: one uv per vertex position, shared where faces meet
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy((pts[:, :2] / span[:2]).astype(np.float32)))
    st.SetIndices(Vt.IntArray(list(spec.indices)))
    # uniform, indexed: a region id per face
    region = api.CreatePrimvar("region", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform)
    region.Set(Vt.IntArray([10, 20]))
    region.SetIndices(Vt.IntArray([0 if f < nf // 2 else 1 for f in range(nf)]))
    # uniform float, not indexed
    api.CreatePrimvar("faceShade", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform).Set(
        Vt.FloatArray([f / max(nf - 1, 1) for f in range(nf)]))
    # constant: left as it is
    api.CreatePrimvar("label", Sdf.ValueTypeNames.String, UsdGeom.Tokens.constant).Set("plate")
    # a face subset (the first row of faces) bound to a material
    material = UsdShade.Material.Define(stage, "/World/Looks/Red")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/Red/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.8, 0.2, 0.2))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    subset = UsdGeom.Subset.CreateGeomSubset(mesh, "FirstRow", UsdGeom.Tokens.face, Vt.IntArray([0, 1, 2, 3]),
                                             familyName="materialBind")
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())


# -- a skinned character -------------------------------------------------------------------------------------

SKINNED = "skinned_character"  # the scene of write_skinned_character (not in SCENES: its points are posed)
SKINNED_VIEW = ("-20", "10")  # its preview's azimuth and elevation


def _tube(rings: int, length: float, half: float, z0: float = 0.0):
    """A closed box tube along z: ``rings`` square rings of 4 points, quads between them and both ends capped."""
    square = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    pts = np.array([(half * x, half * y, z0 + length * r / (rings - 1)) for r in range(rings) for x, y in square])
    faces = [[r * 4 + k, r * 4 + (k + 1) % 4, r * 4 + (k + 1) % 4 + 4, r * 4 + k + 4]
             for r in range(rings - 1) for k in range(4)]
    last = (rings - 1) * 4
    faces += [[3, 2, 1, 0], [last, last + 1, last + 2, last + 3]]
    return pts, faces


def write_skinned_character(path: str, *, method: str = "dualQuaternion", blend_shapes: bool = True,
                            geom_bind_transform: bool = True, rigid: bool = True, animated_xform: bool = False,
                            frames: int = 24) -> str:
    """A small skinned character: a Catmull-Clark leg (a capped tube of 5 rings) bound to a two-joint skeleton
    (hip, knee; two influences per point blending across the knee) with ``method`` skinning ("classicLinear" or
    "dualQuaternion"), a SkelAnimation over ``frames`` frames (the hip turns and slides, the knee bends 90
    degrees), and with ``blend_shapes`` a "bulge" shape on the knee ring whose weight rises from 0 to 1; with
    ``geom_bind_transform`` a geomBindTransform; with ``rigid`` a foot box bound rigidly to the knee (constant
    influences); with ``animated_xform`` the leg and foot under an Xform whose translation is animated. The tests
    vary these; scenes/skinned_character.usda is the default."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    layer.documentation = ("warp-subdiv scene skinned_character: a skinned, blend-shaped leg and a rigidly bound "
                           "foot. Written by scenes/make_scenes.py.")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    UsdSkel.Root.Define(stage, "/World/Character")
    skel = UsdSkel.Skeleton.Define(stage, "/World/Character/Skel")
    joints = ["hip", "hip/knee"]
    skel.CreateJointsAttr(joints)
    knee = Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 1))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1), knee]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1), knee]))
    anim = UsdSkel.Animation.Define(stage, "/World/Character/Skel/Anim")
    anim.CreateJointsAttr(joints)
    translations, rotations = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr()
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * 2))
    if blend_shapes:
        anim.CreateBlendShapesAttr(["bulge"])
        shape_weights = anim.CreateBlendShapeWeightsAttr()
    for f in range(1, frames + 1):
        u = (f - 1) / (frames - 1)
        bend = math.radians(90.0 * u)
        turn = 0.2 * bend
        translations.Set(Vt.Vec3fArray([Gf.Vec3f(0.1 * (f - 1), 0, 0), Gf.Vec3f(0, 0, 1)]), f)
        rotations.Set(Vt.QuatfArray([Gf.Quatf(math.cos(turn), Gf.Vec3f(0, 0, math.sin(turn))),
                                     Gf.Quatf(math.cos(bend / 2), Gf.Vec3f(math.sin(bend / 2), 0, 0))]), f)
        if blend_shapes:
            shape_weights.Set(Vt.FloatArray([u]), f)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    parent = "/World/Character"
    if animated_xform:
        offset = UsdGeom.Xform.Define(stage, "/World/Character/Offset").AddTranslateOp()
        for f in range(1, frames + 1):
            offset.Set(Gf.Vec3d(0, 0.3 * (f - 1), 0), f)
        parent += "/Offset"

    def bound_mesh(name, pts, faces, color):
        mesh = UsdGeom.Mesh.Define(stage, f"{parent}/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in faces]))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([i for f in faces for i in f]))
        mesh.CreateSubdivisionSchemeAttr("catmullClark")
        mesh.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*color)]))
        binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
        binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
        if method != "classicLinear":
            binding.CreateSkinningMethodAttr(method)
        return mesh, binding

    pts, faces = _tube(5, 2.0, 0.25)
    leg, binding = bound_mesh("Leg", pts, faces, (0.8, 0.6, 0.5))
    knee_weight = np.clip(pts[:, 2] - 0.5, 0.0, 1.0)
    binding.CreateJointIndicesPrimvar(False, 2).Set(Vt.IntArray([0, 1] * len(pts)))
    binding.CreateJointWeightsPrimvar(False, 2).Set(
        Vt.FloatArray([float(w) for k in knee_weight for w in (1.0 - k, k)]))
    if geom_bind_transform:
        binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0.05, 0, 0)))
    if blend_shapes:
        shape = UsdSkel.BlendShape.Define(stage, leg.GetPath().AppendChild("bulge"))
        ring = [8, 9, 10, 11]  # the knee ring, pushed out sideways
        shape.CreatePointIndicesAttr(Vt.IntArray(ring))
        shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy((pts[ring] * [1.0, 1.0, 0.0]).astype(np.float32)))
        binding.CreateBlendShapesAttr(["bulge"])
        binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
    if rigid:
        foot_pts, foot_faces = _tube(2, 0.3, 0.3, z0=2.0)
        _, foot = bound_mesh("Foot", foot_pts, foot_faces, (0.4, 0.5, 0.8))
        foot.CreateJointIndicesPrimvar(True, 1).Set(Vt.IntArray([1]))
        foot.CreateJointWeightsPrimvar(True, 1).Set(Vt.FloatArray([1.0]))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(layer.ExportToString())
    return path


def write_all(folder: str = HERE) -> list:
    paths = []
    for scene in SCENES.values():
        path = os.path.join(folder, scene.name + ".usda")
        write_scene(scene, path)
        paths.append(path)
    paths.append(write_skinned_character(os.path.join(folder, SKINNED + ".usda")))
    return paths


def render_previews(root: str) -> None:
    """Refine every scene with warp-subdiv and render docs/<scene>.png (control meshes where a scene needs a
    feature this version lacks)."""
    sys.path.insert(0, root)
    from warp_subdiv import cli

    out_dir = os.path.join(root, "out", "previews")
    for scene in SCENES.values():
        src = os.path.join(HERE, scene.name + ".usda")
        refined = os.path.join(out_dir, f"{scene.name}_L{scene.levels}.usda")
        code = cli.main(["refine", src, "-o", refined, "--levels", str(scene.levels), "--device", "cpu", "--quiet"])
        target = refined if code == 0 else src
        cli.main(["render", target, "-o", os.path.join(root, "docs", scene.name + ".png"), "--size", "640x360",
                  "--view", f"{scene.view[0]:g}", f"{scene.view[1]:g}", "--samples", "3", "--device", "cpu"]
                 + (["--cage", src] if code == 0 else []))
    # the skinned character, baked (its pose at every frame) and drawn at its last frame (no cage: the control
    # mesh as stored is the rest pose)
    src = os.path.join(HERE, SKINNED + ".usda")
    refined = os.path.join(out_dir, f"{SKINNED}_L3.usda")
    cli.main(["refine", src, "-o", refined, "--levels", "3", "--device", "cpu", "--quiet"])
    cli.main(["render", refined, "-o", os.path.join(root, "docs", SKINNED + ".png"), "--size", "640x360",
              "--view", *SKINNED_VIEW, "--time", "24", "--samples", "3", "--device", "cpu"])


if __name__ == "__main__":
    written = write_all()
    print("\n".join(os.path.relpath(p) for p in written))
    if "--previews" in sys.argv:
        render_previews(os.path.dirname(HERE))
