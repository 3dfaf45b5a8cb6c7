"""Meshes of a USD bake whose refinement does not fit ``max_memory``: refined in tiles instead of refused.

:func:`choose_tiled` picks, largest first, the meshes to take out of the in-core bake until what is left fits the
memory guard; :func:`without` takes them out of the plan; :class:`TiledMeshes` refines each of them with
:func:`warp_subdiv.refine_tiled` and writes, in the output layer:

* the original mesh deactivated (``active = false``): the composed stage does not show it;
* a sibling ``Xform`` ``<name>_tiles`` with the mesh's local transform (one ``xformOp:transform``, and
  ``!resetXformStack!`` where the mesh resets it), its ``purpose`` and ``visibility`` where authored;
* under it one ``Mesh`` ``tile_0000``, ``tile_0001``, ... per tile, each loading a layer of its own
  (``<output stem>_tiles/<mesh path, digest>/tile_NNNN.usdc``) as a payload: subdivisionScheme "none", the refined
  points (the limit points with ``limit``), extent, faces, ``int64[] warpSubdiv:vertexIds`` and ``faceIds`` (the
  ids its vertices and faces have in ``refine()``), the limit normals with ``normals`` (borders share their
  vertices' ids and bits, so they shade seamlessly), the mesh's orientation and its primvars refined per tile:
  vertex primvars as the points (their limit values with ``limit``), uniform ones following each face's control
  face, face-varying ones refined per tile; its face GeomSubsets with the tile's faces of each (a subset no face
  of the tile is in is left out), their ``elementType``, ``familyName`` and the mesh's ``subsetFamily:*``
  attributes; the tile prims in the output layer carry the mesh's material bindings (every
  ``material:binding*`` relationship, with MaterialBindingAPI), the subsets' bindings likewise, and the mesh's
  constant primvars.

Refused, with an error naming the prim: meshes with time samples (points, primvars, subsets, topology or
transform), skinned meshes, meshes inside instances or variants or shared with identical meshes, bilinear
meshes, meshes with varying primvars, velocities / accelerations or edge GeomSubsets, and LOD variants or
flattened output. The ``tessellate`` command writes the meshes it tessellates in tiles the same way
(:meth:`TiledMeshes.write_tessellated`: points, faces, normals, ids; meshes with non-constant primvars or
GeomSubsets refused too). Distributed bakes (:mod:`~warp_subdiv.usd.distributed`) build a mesh's tables in a task of its
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
    if sp.point_times or sp.topologies or any(pv.times for pv in sp.primvars) or any(s.times for s in sp.subsets):
        refuse(sp, "time samples")
    if UsdGeom.Xformable(sp.prim).TransformMightBeTimeVarying():
        refuse(sp, "a time-varying transform")
    if sp.scheme == "bilinear":
        refuse(sp, "bilinear meshes")
    if sp.point_arrays:
        refuse(sp, "velocities or accelerations")
    if tessellate and sp.subsets:
        refuse(sp, "GeomSubsets")
    edges = [s.path for s in sp.subsets if s.element != "face"]
    if edges:
        refuse(sp, f"edge GeomSubsets ({', '.join(edges)})")
    other = [pv.name for pv in sp.primvars if pv.interpolation != "faceVarying" or tessellate]
    varying = [pv.name for pv in sp.primvars if pv.interpolation == "varying"]
    if tessellate and other:
        refuse(sp, f"vertex, varying, uniform or face-varying primvars ({', '.join(other)})")
    if varying:
        refuse(sp, f"varying primvars ({', '.join(varying)})")
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
        self.warnings: list = []

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
        material bindings, constant primvars, orientation, the tile layers' folder, the mesh's authored
        ``subsetFamily:*`` attributes)."""
        prim = sp.prim
        self.layer.prim(sp.path).SetInfo("active", False)
        xform = self._tiles_xform(prim)
        bindings = [r for r in prim.GetRelationships() if r.GetName().startswith("material:binding")]
        constants = [pv for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars()
                     if pv.GetInterpolation() == UsdGeom.Tokens.constant and pv.HasAuthoredValue()]
        families = [a for a in prim.GetAttributes() if a.GetName().startswith("subsetFamily:") and a.HasAuthoredValue()]
        orientation = prim.GetAttribute("orientation").Get() if prim.GetAttribute("orientation") else None
        folder = os.path.join(self.folder, tile_folder_name(sp.path))
        self.created += make_folders(folder)
        return xform, bindings, constants, orientation, folder, families

    def _write_tile(self, target: tuple, count: int, tile, points, primvars, subsets=()) -> None:
        """Save tile number ``count`` as a layer of its own and add its prim under the Xform of ``target``
        (:meth:`_begin`); ``subsets``: (name, the tile's face indices, family name, binding relationships) of
        each face subset that holds faces of the tile (:meth:`_TileSubsets.of`)."""
        xform, bindings, constants, orientation, folder, families = target
        name = f"tile_{count:04d}"
        final = os.path.join(folder, name + ".usdc")
        fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=".usdc", dir=folder)
        os.close(fd)
        self.written.append((tmp, final))
        save_tile_layer(tmp, final, tile, points=points, primvars=primvars, orientation=orientation,
                        subsets=[(n, indices, family) for n, indices, family, _ in subsets],
                        attributes=[(a.GetName(), a.GetTypeName(), a.Get()) for a in families])
        child = Sdf.PrimSpec(xform, name, Sdf.SpecifierDef, "Mesh")
        child.payloadList.Prepend(Sdf.Payload(self._relative(final)))
        _bind(child, bindings)
        for subset_name, _, _, subset_bindings in subsets:
            if subset_bindings:
                _bind(Sdf.PrimSpec(child, subset_name, Sdf.SpecifierOver), subset_bindings)
        for pv in constants:
            attr = pv.GetAttr()
            spec = Sdf.AttributeSpec(child, attr.GetName(), attr.GetTypeName())
            spec.default = attr.Get()
            spec.SetInfo("interpolation", UsdGeom.Tokens.constant)

    def _write_mesh(self, sp, level, options) -> PrimReport:
        target = self._begin(sp)
        per_tile = _TilePrimvars(sp)
        subsets = _TileSubsets(sp)
        # every primvar and face-varying channel in the one pass over the tiles
        tiles = refine_tiled(sp.mesh, level, max_memory=self.max_memory, options=options, device=self.device,
                             limit_points=bool(self.limit), limit_normals=bool(self.normals),
                             face_varying=per_tile.channels or None, vertex_data=per_tile.vertex_rows or None)
        count = vertices = faces = 0
        for tile in tiles:
            points = tile.limit_points if self.limit else tile.points
            self._write_tile(target, count, tile, points, per_tile.of(tile, self.limit), subsets.of(tile))
            count += 1
            vertices += tile.num_vertices
            faces += tile.num_faces
        self.warnings.extend(subsets.warnings)
        return PrimReport(path=sp.path, scheme=sp.scheme, rules=options.rules.value, faces_in=sp.mesh.num_faces,
                          faces_out=faces, vertices_in=sp.mesh.num_vertices, vertices_out=vertices, samples=1,
                          level=level)

    def _tiles_xform(self, prim) -> Sdf.PrimSpec:
        """The Xform ``<name>_tiles`` beside ``prim`` with its local transform, purpose and visibility."""
        tiles_path = prim.GetPath().GetParentPath().AppendChild(prim.GetName() + "_tiles")
        xform = Sdf.CreatePrimInLayer(self.layer.layer, tiles_path)
        xform.specifier = Sdf.SpecifierDef
        xform.typeName = "Xform"
        T = Sdf.ValueTypeNames
        xformable = UsdGeom.Xformable(prim)
        order = ["!resetXformStack!"] if xformable.GetResetXformStack() else []
        Sdf.AttributeSpec(xform, "xformOp:transform", T.Matrix4d).default = xformable.GetLocalTransformation()
        order.append("xformOp:transform")
        Sdf.AttributeSpec(xform, "xformOpOrder", T.TokenArray, Sdf.VariabilityUniform).default = order
        for name, variability in (("purpose", Sdf.VariabilityUniform), ("visibility", Sdf.VariabilityVarying)):
            attr = prim.GetAttribute(name)
            if attr and attr.HasAuthoredValue():
                Sdf.AttributeSpec(xform, name, T.Token, variability).default = attr.Get()
        return xform

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


def _bind(spec: Sdf.PrimSpec, bindings) -> None:
    """Author the material binding relationships ``bindings`` (of another prim) on ``spec``, with
    MaterialBindingAPI."""
    if not bindings:
        return
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["MaterialBindingAPI"]))
    for rel in bindings:
        target = Sdf.RelationshipSpec(spec, rel.GetName(), custom=False)
        target.targetPathList.explicitItems = rel.GetTargets()


class _TilePrimvars:
    """A mesh's vertex, uniform and face-varying primvars (at the default time) as a tiled refinement takes
    them (:attr:`vertex_rows`, :attr:`channels`) and as each tile writes them (:meth:`of`), the values the in-core
    bake writes for the same vertices and faces."""

    def __init__(self, sp):
        self.sp = sp
        self.vertex = [pv for pv in sp.primvars if pv.interpolation == "vertex"]
        self.uniform = [pv for pv in sp.primvars if pv.interpolation == "uniform"]
        self.face_varying = [pv for pv in sp.primvars if pv.interpolation == "faceVarying"]
        self.vertex_rows = [self._rows(pv, sp.mesh.num_vertices) for pv in self.vertex]
        self.uniform_values = [self._uniform(pv) for pv in self.uniform]
        mode = sp.face_varying_mode
        self.channels = [(*face_varying_input(sp, pv, DEFAULT)[:2], mode) for pv in self.face_varying]
        # each primvar's values as authored (read once): what the written arrays are shaped like
        self.like = {pv.name: np.asarray(pv.raw(DEFAULT)[0]) for pv in sp.primvars}

    def _rows(self, pv, expected: int) -> np.ndarray:
        rows = pv.flattened(DEFAULT, self.sp.path)
        if len(rows) != expected:
            raise SubdivInputError(f"{self.sp.path}: {pv.name} has {len(rows)} {pv.interpolation} values, the mesh "
                                   f"needs {expected}")
        return rows.astype(np.float64) if pv.interpolation == "vertex" else rows

    def _uniform(self, pv):
        """(values as authored, indices per face) of an indexed uniform primvar; (rows per face, None) else."""
        faces = self.sp.mesh.num_faces
        if not pv.indexed:
            return self._rows(pv, faces), None
        _, idx = pv.elements(DEFAULT, self.sp.path)
        if idx is None or len(idx) != faces:
            raise SubdivInputError(f"{self.sp.path}: {pv.name}:indices has {0 if idx is None else len(idx)} entries "
                                   f"for {faces} faces")
        return pv.raw(DEFAULT)[0], idx

    def of(self, tile, limit: bool) -> list:
        """(name, type name, values, indices or None, interpolation) of every primvar on ``tile``."""
        out = []

        def shaped(pv, rows):
            like = self.like[pv.name]
            rows = np.asarray(rows).reshape(len(rows), -1)
            return vt_array(pv.type_name, rows.reshape((len(rows) * pv.element_size,) + like.shape[1:]), like)

        data = tile.limit_vertex_data if limit else tile.vertex_data
        for k, pv in enumerate(self.vertex):
            out.append((pv.name, pv.type_name, shaped(pv, data[k]), None, "vertex"))
        for pv, (values, idx) in zip(self.uniform, self.uniform_values):
            if idx is None:
                out.append((pv.name, pv.type_name, shaped(pv, values[tile.face_parent]), None, "uniform"))
            else:
                out.append((pv.name, pv.type_name, values, idx[tile.face_parent], "uniform"))
        channels = tile.face_varying if self.face_varying else []
        for pv, channel in zip(self.face_varying, channels):
            out.append((pv.name, pv.type_name, shaped(pv, channel.values), channel.indices, "faceVarying"))
        return out


class _TileSubsets:
    """A mesh's face GeomSubsets (at the default time), remapped per tile (:meth:`of`); a subset whose indices are
    not faces of the mesh is left out, with a warning (as the in-core bake drops it)."""

    def __init__(self, sp):
        self.subsets, self.warnings = [], []
        n = sp.mesh.num_faces
        for subset in sp.subsets:
            value = subset.attr.Get(DEFAULT)
            ids = np.asarray([] if value is None else value, dtype=np.int64)
            bad = np.flatnonzero((ids < 0) | (ids >= n))
            if len(bad):
                self.warnings.append(f"{subset.path}: indices[{bad[0]}] = {ids[bad[0]]} is not a face of the mesh; "
                                     "the subset is dropped")
                continue
            member = np.zeros(n, dtype=bool)
            member[ids] = True
            geom = UsdGeom.Subset(subset.attr.GetPrim())
            family = geom.GetFamilyNameAttr().Get() if geom.GetFamilyNameAttr().HasAuthoredValue() else None
            bindings = [r for r in geom.GetPrim().GetRelationships() if r.GetName().startswith("material:binding")]
            self.subsets.append((geom.GetPrim().GetName(), member, family, bindings))

    def of(self, tile) -> list:
        """(name, the tile's face indices in it, family name or None, binding relationships) of every subset that
        holds faces of ``tile``."""
        out = []
        for name, member, family, bindings in self.subsets:
            indices = np.flatnonzero(member[tile.face_parent])
            if len(indices):
                out.append((name, indices, family, bindings))
        return out


def tile_folder_name(path: str) -> str:
    """The folder of one mesh's tile layers: its path with "/" as "_", and a digest of the path, so that meshes
    whose flattened paths coincide (``/A_B/C``, ``/A/B_C``) get folders of their own."""
    return f"{path.strip('/').replace('/', '_')}_{hashlib.sha1(path.encode()).hexdigest()[:8]}"


__all__ = ["TiledMeshes", "check_tileable", "choose_tiled", "without"]
