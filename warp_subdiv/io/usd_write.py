"""Writing the refined meshes: a new layer that sublayers the input and overrides each refined mesh in place.

The layer is authored with Sdf specs only (no second composition of the scene). It is created next to the
output file under a temporary name, saved, and renamed over the output at the end, so a failure at any point
leaves no partial file. The input file is only ever opened for reading.
"""
from __future__ import annotations

import ctypes
import os
import re
import tempfile

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdUtils, Vt

from ..runtime import phases as _phases
from ..errors import SubdivInputError
from .files import publish
from .usd_stage import DEFAULT, times_for_frames

USD_EXTENSIONS = (".usd", ".usda", ".usdc")
#: Layer metadata that is the input's own business and is not copied to the output layer (customLayerData is
#: merged with the bake's own, :class:`OutputLayer`).
_NOT_COPIED = {"subLayers", "subLayerOffsets", "primChildren", "comment", "documentation", "customLayerData",
               "owner", "sessionOwner", "hasOwnedSubLayers"}


def make_folders(folder: str) -> list:
    """Create ``folder`` and its missing ancestors; the folders created, deepest first (for
    :func:`remove_folders` when the run fails). OSError as os.makedirs raises it."""
    created = []
    path = os.path.abspath(folder)
    while not os.path.exists(path) and os.path.dirname(path) != path:
        created.append(path)
        path = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    return created


def remove_folders(created) -> None:
    """Remove the folders :func:`make_folders` created (deepest first), where they are still empty."""
    for path in created:
        try:
            os.rmdir(path)
        except OSError:
            return  # not empty (someone else wrote there) or gone: leave it and its ancestors


def files_read(stage: Usd.Stage) -> set:
    """The real paths of the files ``stage`` reads or may read: the layers it uses (its layer stack, the layers
    it references, the value clips it opened) and every layer and asset its root layer depends on
    (``UsdUtils.ComputeAllDependencies``: also the references of variants not selected, payloads not loaded and
    value clips not opened yet), so that a run never writes over anything the input may compose."""
    paths = [layer.realPath for layer in stage.GetUsedLayers()]
    root = stage.GetRootLayer()
    if not root.anonymous:
        layers, assets, _ = UsdUtils.ComputeAllDependencies(root.identifier)
        paths += [layer.realPath for layer in layers] + list(assets)
    return {os.path.realpath(p) for p in paths if p}


def check_output_path(output: str, stage: Usd.Stage | None = None, *, folders=(), reads=()) -> str:
    """Absolute output path, as given (symbolic links not resolved: USD anchors the relative sublayer path to
    the path a layer is opened by); refuses unknown extensions and any file the input ``stage`` reads
    (:func:`files_read`) or the run reads besides it (``reads``: files). ``folders``: the folders the run
    replaces next to the output (a distributed bake's chunks): refused where they hold a file read."""
    ext = os.path.splitext(output)[1].lower()
    if ext not in USD_EXTENSIONS:
        raise SubdivInputError(f"{output}: the output of a USD refinement must end in .usd, .usda or .usdc")
    given = os.path.abspath(output)
    out = os.path.realpath(given)  # for comparisons with the files the input reads
    if os.path.isdir(out):
        raise SubdivInputError(f"{output}: is a folder")
    folder = os.path.dirname(out)
    while not os.path.exists(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)  # the nearest existing ancestor: the rest will be created
    if not os.path.isdir(folder):
        raise SubdivInputError(f"{output}: cannot write there: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SubdivInputError(f"{output}: cannot write there: {folder} is not writable")
    read = (files_read(stage) if stage is not None else set()) | {os.path.realpath(p) for p in reads}
    if out in read:
        raise SubdivInputError(f"{output}: the input reads this file; write the refined layer somewhere else")
    for replaced in folders:
        real = os.path.realpath(replaced)
        inside = sorted(p for p in read if p == real or p.startswith(real + os.sep))
        if inside:
            raise SubdivInputError(f"{output}: its folder {replaced} would be replaced, and the input reads "
                                   f"{inside[0]} there; write the refined layer somewhere else")
    return given


def check_flatten(flatten: bool, all_variants: bool) -> None:
    """Refuse ``flatten`` with ``all_variants``: a flattened layer is the composed stage, which holds the
    selected variant of each variant set only (``Usd.Stage.Flatten``), so every other variant refined would be
    dropped. Flattening the output's layer stack instead (``UsdUtils.FlattenLayerStack``) keeps the variant
    sets but also the input's references and payloads: not the self-contained layer ``flatten`` promises."""
    if flatten and all_variants:
        raise SubdivInputError(
            "all_variants and flatten cannot be combined: a flattened layer is the composed stage, which holds the "
            "selected variant of each variant set only, so the variants refined with all_variants would be "
            "dropped; refine with all_variants alone (a layer over the input that keeps every variant set) or "
            "with flatten alone (one self-contained layer of the selected variants)",
            option=("all_variants", "flatten"))


def relative_asset_path(target: str, anchor_dir: str) -> str:
    """``target`` relative to ``anchor_dir`` as an anchored USD asset path ("./x.usda", "../a/x.usd")."""
    try:
        rel = os.path.relpath(target, anchor_dir)
    except ValueError:  # another drive (Windows)
        return target.replace(os.sep, "/")
    rel = rel.replace(os.sep, "/")
    return rel if rel.startswith("../") else "./" + rel


class OutputLayer:
    """The refined layer under construction, at a temporary path in the output's folder. It takes the input
    root layer's metadata (stage metadata, customLayerData merged with ``custom_data``, whose keys win)."""

    def __init__(self, output: str, input_stage: Usd.Stage, custom_data: dict | None = None):
        self.output = output
        self.tmp = None
        self.created = []  # folders this run made: removed again if it fails
        folder = os.path.dirname(output)
        try:
            self.created = make_folders(folder)
            fd, self.tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=os.path.splitext(output)[1], dir=folder)
            os.close(fd)
        except OSError as exc:
            remove_folders(self.created)
            raise SubdivInputError(f"{output}: cannot write there: {exc.strerror or exc}") from None
        try:
            self.layer = Sdf.Layer.CreateNew(self.tmp)
            if self.layer is None:
                raise SubdivInputError(f"{output}: cannot create a USD layer there")
            source = input_stage.GetRootLayer()
            for key in source.pseudoRoot.ListInfoKeys():
                if key not in _NOT_COPIED:
                    self.layer.pseudoRoot.SetInfo(key, source.pseudoRoot.GetInfo(key))
            src_path = source.realPath or source.identifier
            self.source = src_path
            self.layer.subLayerPaths.append(relative_asset_path(src_path, folder))
            # the output becomes the stage's root layer: the input root layer's customLayerData (render
            # settings, studio tags) stays with it, the bake's own entries (one key) replacing the input's
            custom = dict(source.customLayerData)
            custom.update(custom_data or {})
            if custom:
                self.layer.customLayerData = custom
        except BaseException:
            self.discard()
            raise

    # -- authoring -------------------------------------------------------------------------------------
    def prim(self, path: str) -> Sdf.PrimSpec:
        return Sdf.CreatePrimInLayer(self.layer, Sdf.Path(path))

    def attr(self, prim: Sdf.PrimSpec, name: str, type_name, uniform: bool = False,
             custom: bool = False) -> Sdf.AttributeSpec:
        spec = prim.attributes.get(name) if name in prim.attributes else None
        if spec is None:
            variability = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
            spec = Sdf.AttributeSpec(prim, name, type_name, variability, custom)
        return spec

    @_phases.timed("write")
    def set(self, spec: Sdf.AttributeSpec, default=None, samples=None) -> None:
        """Author a default value and/or time samples ((time, value) pairs)."""
        if default is not None:
            spec.default = default
        for time, value in samples or ():
            self.layer.SetTimeSample(spec.path, time, value)

    @_phases.timed("write")
    def copy(self, source, dest) -> None:
        """Copy the spec at ``source`` (a refined mesh, its attributes, time samples and children; or one
        attribute) to ``dest`` (which may lie inside a variant), replacing what ``dest`` held."""
        dest = Sdf.Path(str(dest))
        Sdf.CreatePrimInLayer(self.layer, dest.GetPrimPath())  # its parents, variant sets and variants
        if not Sdf.CopySpec(self.layer, Sdf.Path(str(source)), self.layer, dest):
            raise SubdivInputError(f"{self.output}: could not copy {source} to {dest}")

    def reference(self, path, target) -> None:
        """Prepend an internal reference to ``target`` (a prim of this layer) on ``path``: stronger than the
        prim's own references, weaker than its local opinions."""
        self.prim(str(path)).referenceList.Prepend(Sdf.Reference("", Sdf.Path(str(target))))

    def unreference(self, path, target) -> None:
        """Remove the reference :meth:`reference` authored."""
        spec = self.layer.GetPrimAtPath(Sdf.Path(str(path)))
        if spec is not None:
            spec.referenceList.prependedItems.remove(Sdf.Reference("", Sdf.Path(str(target))))

    def remove(self, path) -> None:
        """Remove the prim spec at ``path`` and everything under it."""
        spec = self.layer.GetPrimAtPath(Sdf.Path(str(path)))
        if spec is not None:
            del spec.realNameParent.nameChildren[spec.name]

    def container(self, path) -> None:
        """The root prim that holds refined prototypes and shared meshes: a class, so that it is not part of
        the scene (nothing traverses or renders it; only references bring its content in)."""
        self.prim(str(path)).specifier = Sdf.SpecifierClass

    def block(self, prim: Sdf.PrimSpec, name: str, type_name, uniform: bool = False, custom: bool = False) -> None:
        """Block the attribute: weaker layers' values (defaults and time samples) no longer show through, and
        neither do time samples this layer may already hold for it."""
        spec = self.attr(prim, name, type_name, uniform, custom)
        for time in self.layer.ListTimeSamplesForPath(spec.path):
            self.layer.EraseTimeSample(spec.path, time)
        spec.default = Sdf.ValueBlock()

    @_phases.timed("write")
    def override_extents_hints(self, input_stage: Usd.Stage, mesh_times: dict, frames=None) -> list:
        """Recompute, in this layer, the ``extentsHint`` (UsdGeom.ModelAPI) that a refined mesh or any of its
        ancestors authors: refinement may leave the control hull (prescribed normals, concave corners), and a
        hint computed for the control mesh would then no longer contain it. ``mesh_times``: refined mesh path
        -> the time samples written for its points. The hint is written at the default time and at the union
        of the times of the meshes under it and its own selected samples. Returns the prim paths overridden."""
        hinted: dict = {}
        for path, times in mesh_times.items():
            prim = input_stage.GetPrimAtPath(path)
            while prim and not prim.IsPseudoRoot():
                attr = prim.GetAttribute("extentsHint")
                if attr and attr.HasAuthoredValue():
                    own = times_for_frames(attr.GetTimeSamples(), frames)
                    hinted.setdefault(str(prim.GetPath()), set()).update(times, own)
                prim = prim.GetParent()
        if not hinted:
            return []
        stage = Usd.Stage.Open(self.layer)
        purposes = UsdGeom.Imageable.GetOrderedPurposeTokens()
        for path, times in sorted(hinted.items()):
            model = UsdGeom.ModelAPI(stage.GetPrimAtPath(path))
            spec = self.attr(self.prim(path), "extentsHint", Sdf.ValueTypeNames.Float3Array)
            self.set(spec, model.ComputeExtentsHint(UsdGeom.BBoxCache(DEFAULT, purposes)))
            for t in sorted(times):
                self.set(spec, samples=[(t, model.ComputeExtentsHint(UsdGeom.BBoxCache(t, purposes)))])
        del stage
        return sorted(hinted)

    # -- finishing -------------------------------------------------------------------------------------
    @_phases.timed("write")
    def commit(self, flatten: bool = False, flattened: Sdf.Layer | None = None) -> None:
        """Save (or flatten) to the temporary file and rename it over the output. A layer that records
        variants refined with all_variants (customLayerData) is not flattened (:func:`check_flatten`).
        ``flattened``: a flattened layer built from this one elsewhere, written instead of it."""
        try:
            if flattened is not None:
                flattened.documentation = (f"Generated by warp-subdiv from the composed stage of {self.output} over "
                                           f"{getattr(self, 'source', '?')}, flattened")
                if not flattened.Export(self.tmp):
                    raise SubdivInputError(f"{self.output}: could not write the flattened layer")
            elif flatten:
                check_flatten(flatten, bool((self.layer.customLayerData.get("warpSubdiv") or {}).get("allVariants")))
                stage = Usd.Stage.Open(self.layer)
                flat = stage.Flatten()
                del stage
                # Flatten's doc names the root layer: here the temporary file, gone once renamed
                flat.documentation = (f"Generated by warp-subdiv from the composed stage of {self.output} over "
                                      f"{getattr(self, 'source', '?')}, flattened")
                if not flat.Export(self.tmp):
                    raise SubdivInputError(f"{self.output}: could not write the flattened layer")
            elif not self.layer.Save():
                raise SubdivInputError(f"{self.output}: could not save the layer")
            publish(self.tmp, self.output)
        except OSError as exc:
            self.discard()
            raise SubdivInputError(f"{self.output}: cannot write: {exc.strerror or exc}") from None
        except BaseException:
            self.discard()
            raise
        self.layer = None
        self.created = []  # the output is there: its folders stay
        existing = Sdf.Layer.Find(self.output)
        if existing is not None:
            existing.Reload(force=True)  # a layer this process opened before now reads the new file

    def flatten(self) -> Sdf.Layer:
        """This layer's stage (over the input) flattened, in memory: the layer stays as it is."""
        stage = Usd.Stage.Open(self.layer)
        return stage.Flatten()

    def discard(self) -> None:
        """Forget the layer and remove its temporary file, and the folders this run created."""
        self.layer = None
        if getattr(self, "tmp", None) and os.path.exists(self.tmp):
            os.unlink(self.tmp)
        remove_folders(getattr(self, "created", []))
        self.created = []


def from_numpy(cls, arr: np.ndarray):
    """``cls.FromNumpy(arr)`` (a Vt array class, numeric ``arr`` of its layout), but about 15x faster and
    without holding the GIL: usd-core's FromNumpy converts element by element with the GIL held (4.6 ms for
    800,000 ints against 0.3 ms for one memcpy), which stalls every other thread of a bake. A new array of the
    length is allocated and its storage, which the Vt array exports through the buffer protocol (read-only),
    is filled with one ``ctypes.memmove`` (a foreign call: the GIL is released). Used where the export has the
    array's layout and, for this class, is checked to be the array's own storage (:func:`_exports_storage`);
    FromNumpy converts everything else."""
    arr = np.ascontiguousarray(arr)
    if arr.size and _exports_storage(cls):
        out = cls(len(arr))
        view = np.asarray(out)
        if view.dtype == arr.dtype and view.shape == arr.shape and view.flags.c_contiguous:
            ctypes.memmove(view.ctypes.data, arr.ctypes.data, arr.nbytes)
            return out
    return cls.FromNumpy(arr)


_STORAGE: dict = {}  # Vt array class -> whether its buffer export is its storage (checked once)


def _exports_storage(cls) -> bool:
    """Whether a new ``cls`` array's buffer export is its own storage: bytes written there (a pattern of
    distinct values) read back through the Vt API (``==`` against FromNumpy of the same values)."""
    known = _STORAGE.get(cls)
    if known is None:
        known = False
        try:
            probe = cls(5)
            view = np.asarray(probe)
            if view.size and view.dtype.kind in "fiub" and view.flags.c_contiguous:
                pattern = (np.arange(view.size) % 7 + 1).astype(view.dtype).reshape(view.shape)
                ctypes.memmove(view.ctypes.data, pattern.ctypes.data, pattern.nbytes)
                known = bool(probe == cls.FromNumpy(pattern))
        except Exception:  # noqa: BLE001 (Boost.Python raises its own exception types; then FromNumpy it is)
            known = False
        _STORAGE[cls] = known
    return known


@_phases.timed("write")
def vt_array(type_name: Sdf.ValueTypeName, values: np.ndarray, like=None):
    """A numpy array as the Vt array of ``type_name`` (rows of vectors, or scalars)."""
    cls = type_name.type.pythonClass
    arr = np.asarray(values)
    dtype = np.asarray(like).dtype if like is not None and len(like) else None
    if dtype is not None and dtype.kind in "fiub" and arr.dtype != dtype:
        arr = arr.astype(dtype)
    if arr.dtype.kind in "fiub":
        try:
            return from_numpy(cls, arr)
        except Exception:  # noqa: BLE001 (Boost.Python raises its own exception types here)
            pass
    return cls([v.tolist() if isinstance(v, np.ndarray) else v for v in arr])


@_phases.timed("write")
def int_array(values) -> Vt.IntArray:
    return from_numpy(Vt.IntArray, np.asarray(values, dtype=np.int32))


@_phases.timed("write")
def vec3f_array(values) -> Vt.Vec3fArray:
    return from_numpy(Vt.Vec3fArray, np.asarray(values, dtype=np.float32).reshape(-1, 3))


@_phases.timed("write")
def extent_of(points: np.ndarray) -> Vt.Vec3fArray:
    pts = np.asarray(points)
    if pts.dtype.kind != "f":
        pts = pts.astype(np.float64)
    pts = pts.reshape(-1, 3)  # float32 points: min and max need no float64 copy (the extent is float3 anyway)
    if len(pts) == 0:
        return vec3f_array(np.zeros((2, 3)))
    # column by column: numpy's reduction over axis 0 of an (n, 3) array is ten times slower
    return vec3f_array(np.array([[pts[:, j].min() for j in range(3)], [pts[:, j].max() for j in range(3)]]))


def write_mesh_layer(output: str, name: str, points, face_vertex_counts, face_vertex_indices) -> None:
    """A new layer with one refined mesh at /<name> (for OBJ input written as USD)."""
    prim_name = re.sub(r"[^A-Za-z0-9_]", "_", name) or "Mesh"
    if prim_name[0].isdigit():
        prim_name = "_" + prim_name
    folder = os.path.dirname(output)
    fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=os.path.splitext(output)[1], dir=folder)
    os.close(fd)
    try:
        layer = Sdf.Layer.CreateNew(tmp)
        prim = Sdf.CreatePrimInLayer(layer, "/" + prim_name)
        prim.specifier = Sdf.SpecifierDef
        prim.typeName = "Mesh"
        layer.defaultPrim = prim_name
        T = Sdf.ValueTypeNames
        Sdf.AttributeSpec(prim, "subdivisionScheme", T.Token, Sdf.VariabilityUniform).default = "none"
        Sdf.AttributeSpec(prim, "points", T.Point3fArray).default = vec3f_array(points)
        Sdf.AttributeSpec(prim, "extent", T.Float3Array).default = extent_of(points)
        Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = int_array(face_vertex_counts)
        Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = int_array(face_vertex_indices)
        if not layer.Save():
            raise OSError(f"could not save {output}")
        del layer
        publish(tmp, output)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    existing = Sdf.Layer.Find(output)
    if existing is not None:
        existing.Reload(force=True)


def _prim_name(name: str) -> str:
    """``name`` as a USD prim name (other characters become "_"; a leading digit gets a "_" before it)."""
    prim_name = re.sub(r"[^A-Za-z0-9_]", "_", name) or "Mesh"
    return "_" + prim_name if prim_name[0].isdigit() else prim_name


def save_tile_layer(path: str, final: str, tile, points=None, primvars=(), orientation: str | None = None,
                    subsets=(), attributes=()) -> None:
    """Save one tile of :func:`warp_subdiv.refine_tiled` as a layer at ``path`` (``final``: the name it will have,
    for the error): a Mesh /tile (its default prim) with subdivisionScheme "none", ``points`` (default: the
    tile's), extent, faces, the ids its vertices and faces have in the in-core refinement as ``int64[]
    warpSubdiv:vertexIds`` and ``warpSubdiv:faceIds``, and the tile's limit normals as ``normals`` where it has
    them. ``primvars``: (name, type name, values, indices or None, interpolation) written as they are;
    ``orientation``: authored when given; ``subsets``: (name, face indices, family name or None), written as
    face GeomSubsets under the mesh; ``attributes``: (name, type name, value) authored on the mesh as they are
    (uniform: the mesh's ``subsetFamily:*`` attributes)."""
    T = Sdf.ValueTypeNames
    points = tile.points if points is None else points
    layer = Sdf.Layer.CreateNew(path)
    prim = Sdf.CreatePrimInLayer(layer, "/tile")
    prim.specifier = Sdf.SpecifierDef
    prim.typeName = "Mesh"
    layer.defaultPrim = "tile"
    Sdf.AttributeSpec(prim, "subdivisionScheme", T.Token, Sdf.VariabilityUniform).default = "none"
    if orientation is not None:
        Sdf.AttributeSpec(prim, "orientation", T.Token, Sdf.VariabilityUniform).default = orientation
    Sdf.AttributeSpec(prim, "points", T.Point3fArray).default = vec3f_array(points)
    Sdf.AttributeSpec(prim, "extent", T.Float3Array).default = extent_of(points)
    Sdf.AttributeSpec(prim, "faceVertexCounts", T.IntArray).default = int_array(tile.face_vertex_counts)
    Sdf.AttributeSpec(prim, "faceVertexIndices", T.IntArray).default = int_array(tile.face_vertex_indices)
    ids = Sdf.AttributeSpec(prim, "warpSubdiv:vertexIds", T.Int64Array, Sdf.VariabilityUniform)
    ids.custom = True
    ids.default = Vt.Int64Array.FromNumpy(np.ascontiguousarray(tile.vertex_ids, dtype=np.int64))
    face_ids = Sdf.AttributeSpec(prim, "warpSubdiv:faceIds", T.Int64Array, Sdf.VariabilityUniform)
    face_ids.custom = True
    face_ids.default = Vt.Int64Array.FromNumpy(np.ascontiguousarray(tile.face_ids, dtype=np.int64))
    if getattr(tile, "limit_normals", None) is not None:
        normals = Sdf.AttributeSpec(prim, "normals", T.Normal3fArray)
        normals.default = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(tile.limit_normals, dtype=np.float32))
        normals.SetInfo("interpolation", UsdGeom.Tokens.vertex)
    for name, type_name, values, indices, interpolation in primvars:
        spec = Sdf.AttributeSpec(prim, name, type_name)
        spec.default = values
        spec.SetInfo("interpolation", interpolation)
        if indices is not None:
            Sdf.AttributeSpec(prim, name + ":indices", T.IntArray).default = int_array(indices)
    for name, type_name, value in attributes:
        Sdf.AttributeSpec(prim, name, type_name, Sdf.VariabilityUniform).default = value
    for name, indices, family in subsets:
        subset = Sdf.PrimSpec(prim, name, Sdf.SpecifierDef, "GeomSubset")
        Sdf.AttributeSpec(subset, "elementType", T.Token, Sdf.VariabilityUniform).default = UsdGeom.Tokens.face
        Sdf.AttributeSpec(subset, "indices", T.IntArray).default = int_array(indices)
        if family is not None:
            Sdf.AttributeSpec(subset, "familyName", T.Token, Sdf.VariabilityUniform).default = family
    if not layer.Save():
        raise OSError(f"could not save {final}")


def write_tiles(output: str, tiles, kind: str, name: str, header: str = "") -> tuple[int, int, int]:
    """The tiles of a tiled refinement or tessellation written to ``output``: streamed into one OBJ file
    (``kind`` "obj": :func:`warp_subdiv.io.obj.write_obj_tiles`, shared vertices written once, ``header`` its
    comment) or as an Xform ``name`` of tile meshes, one layer each (:func:`write_tiled_mesh_layer`). The output's
    folders are made here and removed again if the write fails; an OS error is a :class:`SubdivInputError` naming
    ``output``. Returns (tiles, vertices, faces) written."""
    from .obj import write_obj_tiles

    created = make_folders(os.path.dirname(os.path.abspath(output)))
    try:
        if kind != "obj":
            return write_tiled_mesh_layer(os.path.abspath(output), name, tiles)
        count = [0]

        def counted():
            for tile in tiles:
                count[0] += 1
                yield tile

        vertices, faces = write_obj_tiles(output, counted(), header=header)
        return count[0], vertices, faces
    except OSError as exc:
        remove_folders(created)
        raise SubdivInputError(f"{output}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        remove_folders(created)
        raise


def write_tiled_mesh_layer(output: str, name: str, tiles) -> tuple[int, int, int]:
    """A refined mesh written tile by tile (the tiles of :func:`warp_subdiv.refine_tiled`), for a mesh whose
    refinement does not fit in memory at once: each tile a layer of its own in the folder ``<output stem>_tiles``
    beside ``output`` (``tile_0000.usdc``, ... : a Mesh with its points, extent, faces, the ids its vertices have in
    the in-core refinement as ``int64[] warpSubdiv:vertexIds``, and its limit normals where the tiles have them),
    saved and released before the next tile is refined; ``output`` holds an Xform /<name> whose children
    ``tile_0000``, ... load those layers as payloads. Tiles share their border vertices (the same ids, the same
    points). The tile layers are written under temporary names and renamed once all are written, then
    ``output``; a failed run removes what it wrote. Returns (tiles, vertices, faces) written (border vertices
    counted in every tile that has them)."""
    prim_name = _prim_name(name)
    stem = os.path.splitext(os.path.abspath(output))[0]
    folder = stem + "_tiles"
    created = make_folders(folder)
    written: list = []  # (temporary, final) paths
    totals = [0, 0, 0]
    try:
        for tile in tiles:
            final = os.path.join(folder, f"tile_{totals[0]:04d}.usdc")
            fd, tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=".usdc", dir=folder)
            os.close(fd)
            written.append((tmp, final))
            save_tile_layer(tmp, final, tile)
            totals[0] += 1
            totals[1] += len(tile.points)
            totals[2] += len(tile.face_vertex_counts)
        fd, root_tmp = tempfile.mkstemp(prefix=".warp-subdiv-", suffix=os.path.splitext(output)[1],
                                        dir=os.path.dirname(stem))
        os.close(fd)
        written.append((root_tmp, os.path.abspath(output)))
        layer = Sdf.Layer.CreateNew(root_tmp)
        root = Sdf.CreatePrimInLayer(layer, "/" + prim_name)
        root.specifier = Sdf.SpecifierDef
        root.typeName = "Xform"
        layer.defaultPrim = prim_name
        # the stage's fallbacks, stated (an OBJ has no units or axis): usd-core's validators ask for them
        layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, UsdGeom.Tokens.y)
        layer.pseudoRoot.SetInfo(UsdGeom.Tokens.metersPerUnit, 0.01)
        for _, final in written[:-1]:
            child = Sdf.PrimSpec(root, os.path.splitext(os.path.basename(final))[0], Sdf.SpecifierDef, "Mesh")
            child.payloadList.Prepend(Sdf.Payload("./" + os.path.basename(folder) + "/" + os.path.basename(final)))
        if not layer.Save():
            raise OSError(f"could not save {output}")
        del layer
        for tmp, final in written:
            publish(tmp, final)
    except BaseException:
        for tmp, final in written:
            for path in (tmp, final):
                if os.path.exists(path) and (path == tmp or path != os.path.abspath(output)):
                    os.unlink(path)
        remove_folders(created)
        raise
    for _, final in written:
        existing = Sdf.Layer.Find(final)
        if existing is not None:
            existing.Reload(force=True)
    return tuple(totals)
