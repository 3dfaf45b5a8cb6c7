"""The adaptive tessellation scene: control meshes, their limit surfaces tessellated by edge length.

    python scenes/make_tessellation_scene.py [--preview]

writes

* ``scenes/adaptive_tessellation_control.usda``: two subdivision meshes: a Catmull-Clark tapered pentagonal tower
  (pentagon caps, so extraordinary face points; an infinitely sharp crease around the top rim and a semi-sharp
  one, sharpness 2, around the bottom) and a Loop ellipsoid (an icosahedron stretched 2.5 times along x);
* ``scenes/adaptive_tessellation.usda``: ``warp-subdiv tessellate ... --edge-length 0.12 --flatten`` of it (a
  self-contained layer: the tessellated meshes, ``subdivisionScheme = "none"``), with a uniform ``displayColor``
  that gives every output face its control face's hue and alternates its brightness, so the facets show: long
  control edges get many segments, short ones few, and neighbouring faces of different rates are stitched;
* with ``--preview``, ``docs/adaptive_tessellation.png``: ``warp-subdiv render`` of the tessellation with its
  edges drawn over it (``--cage`` of a temporary copy whose meshes are marked as subdivision meshes, since the
  cage overlay draws subdivision meshes only).
"""
from __future__ import annotations

import colorsys
import math
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CONTROL = os.path.join(HERE, "adaptive_tessellation_control.usda")
SCENE = os.path.join(HERE, "adaptive_tessellation.usda")
PREVIEW = os.path.join(ROOT, "docs", "adaptive_tessellation.png")
EDGE_LENGTH = 0.12


def tower():
    """Points, counts, indices, creases (pairs), crease sharpness of the tapered pentagonal tower."""
    bottom = [(1.2 * math.cos(2 * math.pi * i / 5), 1.2 * math.sin(2 * math.pi * i / 5), 0.0) for i in range(5)]
    middle = [(0.8 * math.cos(2 * math.pi * (i + 0.3) / 5), 0.8 * math.sin(2 * math.pi * (i + 0.3) / 5), 1.0)
              for i in range(5)]
    top = [(0.35 * math.cos(2 * math.pi * (i + 0.6) / 5), 0.35 * math.sin(2 * math.pi * (i + 0.6) / 5), 1.7)
           for i in range(5)]
    points = np.array(bottom + middle + top, dtype=np.float64)
    faces = [[4, 3, 2, 1, 0], [10, 11, 12, 13, 14]]
    for i in range(5):
        j = (i + 1) % 5
        faces.append([i, j, 5 + j, 5 + i])
        faces.append([5 + i, 5 + j, 10 + j, 10 + i])
    creases = [(10 + i, 10 + (i + 1) % 5) for i in range(5)] + [(i, (i + 1) % 5) for i in range(5)]
    sharpness = [10.0] * 5 + [2.0] * 5
    return points, faces, creases, sharpness


def ellipsoid():
    """Points and faces of an icosahedron stretched 2.5 times along x."""
    g = (1 + 5 ** 0.5) / 2
    pts = np.array([(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g), (0, -1, -g), (0, 1, -g),
                    (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)], dtype=np.float64)
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    pts = pts / np.linalg.norm(pts[0]) * 0.6
    pts[:, 0] *= 2.5
    return pts, [list(f) for f in faces]


def write_control(path: str) -> None:
    from pxr import Gf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    pts, faces, creases, sharp = tower()
    m = UsdGeom.Mesh.Define(stage, "/World/Tower")
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in faces]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([i for f in faces for i in f]))
    m.CreateSubdivisionSchemeAttr("catmullClark")
    m.CreateCreaseIndicesAttr(Vt.IntArray([i for c in creases for i in c]))
    m.CreateCreaseLengthsAttr(Vt.IntArray([2] * len(creases)))
    m.CreateCreaseSharpnessesAttr(Vt.FloatArray(sharp))
    m.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(0.85, 0.55, 0.35)]))
    pts, faces = ellipsoid()
    e = UsdGeom.Mesh.Define(stage, "/World/Ellipsoid")
    e.CreatePointsAttr(Vt.Vec3fArray.FromNumpy((pts + [0.0, 2.4, 0.8]).astype(np.float32)))
    e.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    e.CreateFaceVertexIndicesAttr(Vt.IntArray([i for f in faces for i in f]))
    e.CreateSubdivisionSchemeAttr("loop")
    e.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(0.45, 0.6, 0.85)]))
    stage.GetRootLayer().documentation = "warp-subdiv scenes/make_tessellation_scene.py: control meshes"
    stage.GetRootLayer().Export(path)


def colour_facets(path: str) -> None:
    """Uniform displayColor on every tessellated mesh: its control face's hue."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.Open(path)
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        base = np.asarray(prim.GetAttribute("primvars:tessellation:baseFace").Get(), dtype=np.int64)
        hue = (0.05 + 0.61803 * base) % 1.0
        rgb = np.array([colorsys.hls_to_rgb(h, 0.62, 0.5) for h in hue], dtype=np.float32)
        pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                     UsdGeom.Tokens.uniform)
        pv.Set(Vt.Vec3fArray.FromNumpy(rgb))
    stage.GetRootLayer().Save()


def wire_copy(path: str, wire: str) -> None:
    """A copy of the tessellation whose meshes say catmullClark: ``render --cage`` then draws their edges."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            UsdGeom.Mesh(prim).GetSubdivisionSchemeAttr().Set("catmullClark")
    stage.GetRootLayer().Export(wire)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    write_control(CONTROL)
    cli = [sys.executable, "-m", "warp_subdiv"]
    subprocess.run(cli + ["tessellate", CONTROL, "-o", SCENE, "--edge-length", str(EDGE_LENGTH), "--flatten",
                          "--quiet"], check=True, cwd=ROOT)
    colour_facets(SCENE)
    if "--preview" in argv:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            wire = os.path.join(tmp, "wire.usda")
            wire_copy(SCENE, wire)
            subprocess.run(cli + ["render", SCENE, "-o", PREVIEW, "--cage", wire, "--view", "-60", "28",
                                  "--size", "1000x640"], check=True, cwd=ROOT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
