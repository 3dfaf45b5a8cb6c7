"""Meshes of a USD bake whose refinement does not fit ``max_memory``: refined in tiles instead of refused.

:func:`choose_tiled` picks, largest first, the meshes to take out of the in-core bake until what is left fits the
memory guard; :func:`without` takes them out of the plan; :class:`TiledMeshes` refines each of them with
:func:`warp_subdiv.refine_tiled` and writes, in the output layer:

* the original mesh deactivated (``active = false``): the composed stage does not show it;
* a sibling ``Xform`` ``<name>_tiles`` with the mesh's local transform (one ``xformOp:transform``, and
  ``!resetXformStack!`` where the mesh resets it), its ``purpose`` and ``visibility`` where authored;
* under it one ``Mesh`` ``tile_0000``, ``tile_0001``, ... per tile, each loading a layer of its own
  (``<output stem>_tiles/<mesh path, digest>/tile_NNNN.usdc``) as a payload: subdivisionScheme "none", the refined
  points (the limit points with ``limit``), extent, faces, ``int64[] warpSubdiv:vertexIds`` (the ids its vertices
  have in ``refine()``), the limit normals with ``normals`` (borders share their vertices' ids and bits, so
  they shade seamlessly), the face-varying primvars refined per tile, the mesh's orientation; the tile prims in
  the output layer carry the mesh's material bindings (every ``material:binding*`` relationship, with
  MaterialBindingAPI) and its constant primvars.

Refused, with an error naming the prim: meshes with time samples (points, primvars, topology or transform),
skinned meshes, meshes inside instances or variants or shared with identical meshes, bilinear meshes, meshes
with vertex, varying or uniform primvars, velocities / accelerations or GeomSubsets, and LOD variants or
flattened output. The ``tessellate`` command writes the meshes it tessellates in tiles the same way
(:meth:`TiledMeshes.write_tessellated`: points, faces, normals, ids; face-varying primvars refused too).
Distributed bakes (:mod:`~warp_subdiv.usd.distributed`) build a mesh's tables in a task of its
own under the memory guard, which still refuses a mesh that does not fit.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import time

import numpy as np
from pxr import Sdf, UsdGeom

from ..errors import SubdivInputError
from ..io.files import publish
from ..io.usd_stage import DEFAULT
from ..io.usd_write import OutputLayer, make_folders, remove_folders, save_tile_layer, vt_array
from ..runtime.estimate import RUNTIME_BYTES, check_index_range, memory_limit, total_bytes
from ..tiled import refine_tiled
from .planning import Plan, PrimReport
from .primvars import face_varying_input
from .skinning import SkinnedPrim


def choose_tiled(p: Plan, max_memory) -> list:
    """Indices of the plan's meshes to refine in tiles: none when the bake fits ``max_memory``; else the largest
    meshes, one by one, until the rest fits (all of them if it never does). None either when the limit does not
    even hold Warp's runtime (no tile fits then: the memory guard refuses the bake)."""
    budget = memory_limit(max_memory)
    if budget is None or total_bytes(p.estimates) <= budget or budget <= RUNTIME_BYTES:
        return []
    order = sorted(range(len(p.prims)), key=lambda i: -(p.estimates[i].output_bytes + p.estimates[i].working_bytes))
    chosen = []
    for i in order:
        rest = [e for j, e in enumerate(p.estimates) if j not in chosen]
        if rest and total_bytes(rest) <= budget:
            break
        chosen.append(i)
    return sorted(chosen)


def _refuse(sp, why: str, verb: str = "refined", lower: str = "its level"):
    raise SubdivInputError(f"{sp.path}: does not fit max_memory and is {verb} in tiles, which do not support "
                           f"{why}; raise max_memory or lower {lower}", option="max_memory")


def check_tileable(p: Plan, i: int, *, lod_variants=None, flatten=False, tessellate: bool = False) -> None:
    """Refuse, naming the prim, a mesh that a tiled bake cannot write (see the module docstring); with
    ``tessellate``, a mesh that a tiled tessellation cannot write (face-varying primvars too: its tiles carry
    points, faces and normals only)."""
    sp = p.prims[i]
    key = p.keys[i]

    def refuse(sp, why):
        _refuse(sp, why, *(("tessellated", "its rate") if tessellate else ()))

    if tessellate and any(pv.interpolation == "faceVarying" for pv in sp.primvars):
        refuse(sp, "face-varying primvars")
    if lod_variants:
        refuse(sp, "LOD variants")
    if flatten:
        refuse(sp, "flattened output")
    occurrences = [o for o in p.scene.top.meshes if o.key == key]
    if (len(occurrences) != 1 or occurrences[0].dest.ContainsPrimVariantSelection()
            or str(occurrences[0].dest) != sp.path or any(r.site == key for r in p.scene.top.refs)):
        refuse(sp, "meshes in instances, in variants or shared with identical meshes")
    if isinstance(sp, SkinnedPrim):
        refuse(sp, "skinned meshes")
    if sp.point_times or sp.topologies or any(pv.times for pv in sp.primvars):
        refuse(sp, "time samples")
    if UsdGeom.Xformable(sp.prim).TransformMightBeTimeVarying():
        refuse(sp, "a time-varying transform")
    if sp.scheme == "bilinear":
        refuse(sp, "bilinear meshes")
    if sp.point_arrays:
        refuse(sp, "velocities or accelerations")
    if sp.subsets:
        refuse(sp, "GeomSubsets")
    other = [pv.name for pv in sp.primvars if pv.interpolation != "faceVarying"]
    if other:
        refuse(sp, f"vertex, varying or uniform primvars ({', '.join(other)})")
    parent = sp.prim.GetParent()
    if parent.GetChild(sp.prim.GetName() + "_tiles"):
        refuse(sp, f"a sibling named {sp.prim.GetName()}_tiles (the tiles' name)")
    if not tessellate:
        check_index_range([p.estimates[i]], p.levels[i])


def without(p: Plan, chosen) -> Plan:
    """The plan with the meshes ``chosen`` (indices) taken out (they are refined in tiles instead)."""
    keep = [i for i in range(len(p.prims)) if i not in set(chosen)]
    keys = {p.keys[i] for i in chosen}
    count = len(p.prims)
    for name in ("prims", "keys", "levels", "options", "analyses", "estimates", "tables"):
        values = getattr(p, name)
        if len(values) == count:  # (a tessellation's plan has no levels, estimates, ...)
            setattr(p, name, [values[i] for i in keep])
    p.scene.top.meshes = [o for o in p.scene.top.meshes if o.key not in keys]
    for key in keys:
        p.scene.units.pop(key, None)
    return p


class TiledMeshes:
    """The meshes of a bake refined in tiles (``items``: (SubdivPrim, level, options) each), written into
    ``layer`` by :meth:`write`; their tile layers go into ``<output stem>_tiles/``. :meth:`publish` gives them
    their names once the output is committed; :meth:`discard` removes them."""

    def __init__(self, layer: OutputLayer, output: str, items, *, max_memory, device, limit, normals):
        self.layer, self.items = layer, items
        self.max_memory, self.device, self.limit, self.normals = max_memory, device, limit, normals
        self.folder = os.path.splitext(os.path.abspath(output))[0] + "_tiles"
        self.created: list = []
        self.written: list = []  # (temporary, final)

    def write(self) -> list:
        """Refine and write every tiled mesh; returns a report per mesh."""
        reports = []
        for sp, level, options in self.items:
            start = time.perf_counter()
            report = self._write_mesh(sp, level, options)
            report.seconds = time.perf_counter() - start
            reports.append(report)
        return reports

    def write_tessellated(self, items) -> list:
        """Tessellate in tiles and write every mesh of ``items`` ((SubdivPrim, keywords of
        :func:`warp_subdiv.tessellate_tiled`) each) as the tiled bake writes a refined mesh: the mesh
        deactivated, a sibling Xform of tile meshes (points, faces, normals, ids); returns (mesh path, tiles,
        faces, vertices) per mesh."""
        from ..tiled_tessellation import tessellate_tiled

        out = []
        for sp, keywords in items:
            target = self._begin(sp)
            count = vertices = faces = 0
            for tile in tessellate_tiled(sp.mesh, max_memory=self.max_memory, device=self.device, **keywords):
                if target[3] == UsdGeom.Tokens.leftHanded:  # as the in-core tessellation writes them
                    tile.limit_normals = -tile.limit_normals
                self._write_tile(target, count, tile, tile.points, [])
                count += 1
                vertices += tile.num_vertices
                faces += tile.num_faces
            out.append((sp.path, count, faces, vertices))
        return out

    def _begin(self, sp) -> tuple:
        """Deactivate the mesh and define its tiles' Xform; returns what each tile prim carries: (the Xform spec,
        material bindings, constant primvars, orientation, the tile layers' folder)."""
        layer = self.layer
        prim = sp.prim
        layer.prim(sp.path).SetInfo("active", False)
        tiles_path = prim.GetPath().GetParentPath().AppendChild(prim.GetName() + "_tiles")
        xform = Sdf.CreatePrimInLayer(layer.layer, tiles_path)
        xform.specifier = Sdf.SpecifierDef
        xform.typeName = "Xform"
        T = Sdf.ValueTypeNames
        xformable = UsdGeom.Xformable(prim)
        order = ["!resetXformStack!"] if xformable.GetResetXformStack() else []
        matrix = xformable.GetLocalTransformation()
        Sdf.AttributeSpec(xform, "xformOp:transform", T.Matrix4d).default = matrix
        order.append("xformOp:transform")
        Sdf.AttributeSpec(xform, "xformOpOrder", T.TokenArray, Sdf.VariabilityUniform).default = order
        for name, variability in (("purpose", Sdf.VariabilityUniform), ("visibility", Sdf.VariabilityVarying)):
            attr = prim.GetAttribute(name)
            if attr and attr.HasAuthoredValue():
                Sdf.AttributeSpec(xform, name, T.Token, variability).default = attr.Get()
        bindings = [r for r in prim.GetRelationships() if r.GetName().startswith("material:binding")]
        constants = [pv for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars()
                     if pv.GetInterpolation() == UsdGeom.Tokens.constant and pv.HasAuthoredValue()]
        orientation = prim.GetAttribute("orientation").Get() if prim.GetAttribute("orientation") else None
        folder = os.path.join(self.folder, tile_folder_name(sp.path))
        self.created += make_folders(folder)
        return xform, bindings, constants, orientation, folder

    def _write_tile(self, target: tuple, count: int, tile, points, primvars) -> None:
        """Save tile number ``count`` as a layer of its own and add its prim under the Xform of ``target``
        (:meth:`_begin`)."""
        xform, bindings, constants, orientation, folder = target
        name = f"tile_{count:04d}"
        final = os.path.join(folder, name + ".usdc")
        fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=".usdc", dir=folder)
        os.close(fd)
        self.written.append((tmp, final))
        save_tile_layer(tmp, final, tile, points=points, primvars=primvars, orientation=orientation)
        child = Sdf.PrimSpec(xform, name, Sdf.SpecifierDef, "Mesh")
        child.payloadList.Prepend(Sdf.Payload(self._relative(final)))
        if bindings:
            child.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["MaterialBindingAPI"]))
        for rel in bindings:
            spec = Sdf.RelationshipSpec(child, rel.GetName(), custom=False)
            spec.targetPathList.explicitItems = rel.GetTargets()
        for pv in constants:
            attr = pv.GetAttr()
            spec = Sdf.AttributeSpec(child, attr.GetName(), attr.GetTypeName())
            spec.default = attr.Get()
            spec.SetInfo("interpolation", UsdGeom.Tokens.constant)

    def _write_mesh(self, sp, level, options) -> PrimReport:
        target = self._begin(sp)
        channels = [pv for pv in sp.primvars if pv.interpolation == "faceVarying"]
        mode = sp.face_varying_mode
        want = dict(max_memory=self.max_memory, options=options, device=self.device,
                    limit_points=bool(self.limit), limit_normals=bool(self.normals))
        # one tiled refinement per face-varying channel (the first gives the points too), all with the same tiles:
        # the tiling depends on the mesh, the budget and whether a channel is refined
        runs = [refine_tiled(sp.mesh, level, face_varying=(*face_varying_input(sp, pv, DEFAULT)[:2], mode), **want)
                for pv in channels] or [refine_tiled(sp.mesh, level, **want)]
        count = vertices = faces = 0
        for tiles in zip(*runs):
            tile = tiles[0]
            others = tiles if channels else ()
            primvars = []
            for pv, other in zip(channels, others):
                like = np.asarray(pv.raw(DEFAULT)[0])
                values = np.asarray(other.face_varying.values).reshape(len(other.face_varying.values), -1)
                shaped = values.reshape((len(values) * pv.element_size,) + like.shape[1:])
                primvars.append((pv.name, pv.type_name, vt_array(pv.type_name, shaped, like),
                                 other.face_varying.indices, "faceVarying"))
            points = tile.limit_points if self.limit else tile.points
            self._write_tile(target, count, tile, points, primvars)
            count += 1
            vertices += tile.num_vertices
            faces += tile.num_faces
        return PrimReport(path=sp.path, scheme=sp.scheme, rules=options.rules.value, faces_in=sp.mesh.num_faces,
                          faces_out=faces, vertices_in=sp.mesh.num_vertices, vertices_out=vertices, samples=1,
                          level=level)

    def _relative(self, final: str) -> str:
        anchor = os.path.dirname(self.layer.output)
        return "./" + os.path.relpath(final, anchor).replace(os.sep, "/")

    def publish(self) -> None:
        """Give the tile layers their names (after the output is committed), and remove the tile layers an earlier
        bake left in the same folders that this one no longer references (it wrote fewer tiles)."""
        for tmp, final in self.written:
            publish(tmp, final)
            existing = Sdf.Layer.Find(final)
            if existing is not None:
                existing.Reload(force=True)
        finals = {final for _, final in self.written}
        for folder in {os.path.dirname(final) for final in finals}:
            for name in os.listdir(folder):
                path = os.path.join(folder, name)
                if name.startswith("tile_") and name.endswith(".usdc") and path not in finals:
                    os.unlink(path)

    def discard(self) -> None:
        """Remove the tile layers written (a failed bake)."""
        for tmp, _ in self.written:
            if os.path.exists(tmp):
                os.unlink(tmp)
        remove_folders(self.created)


def tile_folder_name(path: str) -> str:
    """The folder of one mesh's tile layers: its path with "/" as "_", and a digest of the path, so that meshes
    whose flattened paths coincide (``/A_B/C``, ``/A/B_C``) get folders of their own."""
    return f"{path.strip('/').replace('/', '_')}_{hashlib.sha1(path.encode()).hexdigest()[:8]}"


__all__ = ["TiledMeshes", "check_tileable", "choose_tiled", "without"]
