"""The ``tessellate`` command's library side: the limit surfaces of an OBJ or USD file tessellated and written
as OBJ or as a USD layer over the input (primvars and subsets carried to the tessellation).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SubdivInputError
from ..limit import DEFAULT_DEPTH, LimitSurface, corner_weights


@dataclass
class MeshReport:
    """One tessellated mesh, for the command's summary."""

    path: str
    scheme: str
    rules: str
    faces_in: int
    faces_out: int
    vertices_out: int
    seconds: float
    tiles: int = 0  # tessellated in this many tiles (0: in core)


@dataclass
class FileResult:
    """What :func:`tessellate_file` did: one report per mesh, warnings, seconds."""

    reports: list
    warnings: list
    seconds: float


def tessellate_file(input_path: str, output_path: str, *, rate=None, edge_length=None, prims=None, scheme="auto",
                    rules=None, boundary=None, depth=None, quads: bool = True, device=None,
                    flatten: bool = False, frames=None, all_variants: bool = False, camera=None, pixel_error=None,
                    resolution=None, max_memory=None) -> FileResult:
    """Tessellate the limit surfaces of an OBJ or USD file (the ``tessellate`` command's library side).

    OBJ input is written as OBJ or as a USD layer holding one mesh; USD input as a layer over it (see
    :func:`tessellate_usd`). ``rate`` / ``edge_length`` as for :func:`tessellate`; ``prims``, ``scheme``,
    ``rules``, ``boundary`` as for the USD bake; ``depth`` of the :class:`~warp_subdiv.limit.LimitSurface`
    (None: its default); ``quads=False`` for triangles only; ``flatten`` (USD) for one self-contained layer;
    ``all_variants`` (USD) tessellates every variant that changes a mesh, as refine does. ``camera`` (USD, a
    UsdGeom.Camera prim path) with ``pixel_error`` and ``resolution`` instead of ``rate`` / ``edge_length``:
    per-edge rates from the camera (see :func:`tessellate_usd`). ``max_memory`` (bytes; None: no limit): an OBJ
    mesh whose predicted tessellation does not fit is tessellated in tiles
    (:func:`warp_subdiv.tessellate_tiled`), streamed into one OBJ file (shared vertices written once) or written
    as a USD Xform of tile meshes, one layer each (:func:`~warp_subdiv.io.usd_write.write_tiled_mesh_layer`); a
    USD mesh that does not fit is tessellated in tiles as the tiled bake writes refined meshes (see
    :func:`tessellate_usd`). Errors name options by keyword."""
    import os
    import time

    start = time.perf_counter()
    kind, out_kind = _kind(input_path), _kind(output_path)
    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    options = dict(rate=rate, edge_length=edge_length, scheme=scheme, rules=rules, boundary=boundary, depth=depth,
                   quads=quads, device=device, max_memory=max_memory)
    if kind == "obj":
        for name, value in (("prims", prims), ("flatten", flatten), ("frames", frames),
                            ("all_variants", all_variants), ("camera", camera)):
            if value:
                raise SubdivInputError(f"{name} applies to USD input only", option=name)
        reports, warnings_ = tessellate_obj(input_path, output_path, out_kind, **options)
    else:
        if out_kind != "usd":
            raise SubdivInputError(f"{output_path}: USD input is written as .usd, .usda or .usdc")
        reports, warnings_ = tessellate_usd(input_path, output_path, prims=prims, flatten=flatten, frames=frames,
                                            all_variants=all_variants, camera=camera, pixel_error=pixel_error,
                                            resolution=resolution, **options)
    return FileResult(reports, warnings_, time.perf_counter() - start)


def _kind(path: str) -> str:
    ext = path.lower().rsplit(".", 1)[-1] if "." in path else ""
    if ext == "obj":
        return "obj"
    if ext in ("usd", "usda", "usdc"):
        return "usd"
    raise SubdivInputError(f"{path}: unknown file type (use .obj, .usd, .usda or .usdc)")


def _surface(mesh, options, depth, device):
    return LimitSurface(mesh, options=options, depth=DEFAULT_DEPTH if depth is None else depth, device=device)


def tessellate_obj(input_path, output_path, out_kind, *, rate, edge_length, scheme, rules, boundary, depth, quads,
                   device, max_memory=None):
    """Tessellate an OBJ file's mesh; write OBJ or a USD layer holding one mesh (as ``refine`` does); in tiles
    where it would not fit ``max_memory`` (:func:`_tessellate_obj_tiled`)."""
    import os
    import time

    from ..io.obj import read_obj, write_obj
    from ..tiled_tessellation import tessellation_fits
    from .planning import options_for

    t0 = time.perf_counter()
    data = read_obj(input_path)
    options = options_for(data, scheme=scheme, rules=rules, boundary=boundary, precision="float64")
    if max_memory is not None:
        surface_depth = DEFAULT_DEPTH if depth is None else depth
        fits, _ = tessellation_fits(data.mesh, rate=rate, edge_length=edge_length, quads=quads, max_memory=max_memory,
                                    depth=surface_depth, options=options)
        if not fits:
            tiles, faces, vertices = _tessellate_obj_tiled(data, output_path, out_kind, options, rate=rate,
                                                           edge_length=edge_length, quads=quads, depth=surface_depth,
                                                           device=device, max_memory=max_memory)
            return [MeshReport(os.path.basename(input_path), options.scheme.value, options.rules.value,
                               len(data.mesh.face_vertex_counts), faces, vertices, time.perf_counter() - t0,
                               tiles)], []
    surface = _surface(data.mesh, options, depth, device)
    t = surface.tessellate(rate=rate, edge_length=edge_length, quads=quads)
    if out_kind == "obj":
        write_obj(output_path, t.points, t.face_vertex_counts, t.face_vertex_indices)
    else:
        from ..io.usd_write import write_mesh_layer

        name = os.path.splitext(os.path.basename(input_path))[0]
        write_mesh_layer(output_path, name, t.points, t.face_vertex_counts, t.face_vertex_indices)
    report = MeshReport(os.path.basename(input_path), options.scheme.value, options.rules.value,
                        len(data.mesh.face_vertex_counts), t.num_faces, t.num_vertices, time.perf_counter() - t0)
    return [report], []


def _tessellate_obj_tiled(data, output_path, out_kind, options, *, rate, edge_length, quads, depth, device,
                          max_memory) -> tuple:
    """An OBJ mesh's tessellation in tiles (:func:`warp_subdiv.tessellate_tiled`) streamed into one OBJ file
    (shared vertices written once) or written as a USD Xform of tile meshes with their normals, one layer each
    (:func:`~warp_subdiv.io.usd_write.write_tiles`).
    Returns (tiles, faces, vertices) written (border vertices: once in OBJ, in every tile in USD)."""
    import os

    from ..io.usd_write import write_tiles
    from ..tiled_tessellation import tessellate_tiled

    tiles = tessellate_tiled(data.mesh, rate=rate, edge_length=edge_length, quads=quads, max_memory=max_memory,
                             depth=depth, options=options, device=device)
    count, vertices, faces = write_tiles(output_path, tiles, out_kind,
                                         os.path.splitext(os.path.basename(output_path))[0],
                                         header="warp-subdiv: tessellated in tiles")
    return count, faces, vertices


def tessellate_usd(input_path, output_path, *, prims, flatten, rate, edge_length, scheme, rules, boundary, depth,
                   quads, device, frames=None, all_variants: bool = False, camera=None, pixel_error=None,
                   resolution=None, max_memory=None):
    """Tessellate every subdivision mesh of a USD file and write a layer over it, with the conventions of
    refine (:func:`warp_subdiv.usd.refine_usd`): an ``over`` at each mesh's path with ``subdivisionScheme =
    "none"``, its points, faces, normals and extent (at the default time and every selected time sample of the
    points), the subdivision attributes and ``subdiv:`` tags blocked, the ``extentsHint`` of its ancestors
    recomputed; velocities and accelerations evaluated with the points' weights (:func:`_write_samples`).
    Uniform primvars and face subsets follow their control faces, edge subsets hold the output edges on their
    control edges (:class:`TessellationMaps`), vertex and face-varying primvars are evaluated on the limit
    surface, varying ones linearly (:func:`_write_primvars`), those that cannot be interpolated are blocked
    with a warning (:func:`_block_control_attributes`); a mesh bound to a UsdSkel skeleton is tessellated as
    UsdSkel poses it at every time its pose changes, and its binding dropped (refine's ``skinning="bake"``,
    :mod:`warp_subdiv.usd.skinning`); the tessellation's control face and face-varying
    (u, v) are written as ``primvars:tessellation:baseFace`` (uniform) and ``primvars:tessellation:uv``
    (faceVarying).

    Where the data goes is refine's layout (:func:`warp_subdiv.io.usd_scene.read_scene`,
    :func:`warp_subdiv.usd.layout`): meshes inside scene-graph instances (and instanceable PointInstancer
    prototypes) are tessellated once per prototype into ``/__warpSubdiv/Prototype_<n>``, which every instance
    of that prototype references (instances stay instances); meshes with identical inputs outside instances
    are tessellated once, written once (``/__warpSubdiv/Mesh_<n>``) and referenced; with ``all_variants`` every
    variant that changes a mesh is tessellated into the same variant set and variant. The composed output is
    checked: every tessellated mesh must compose to its tessellation.

    ``camera`` (a UsdGeom.Camera prim path) with ``pixel_error`` (pixels > 0) and ``resolution`` (default: the
    stage's render settings, else 1920x1080), instead of ``rate`` and ``edge_length``: each control edge gets
    ceil(the projected length of its limit curve / ``pixel_error``) segments, at the worst time of ``frames``
    (:meth:`warp_subdiv.usd.levels.CameraLevels.edge_rates`: the edge-length mode's curves, measured in pixels
    through the camera); rates are per edge, so the tessellation stays watertight. Meshes off screen get rate
    1; instances and identical meshes placed differently are tessellated apart where their rates differ.
    ``max_memory``: meshes that would not fit are tessellated in tiles (:func:`_choose_tiled`)."""
    import os

    from ..io.usd_write import check_flatten
    from ..version import __version__

    check_flatten(flatten, all_variants)  # before any work, as refine refuses it
    from .output_layout import layout
    from ..io.usd_stage import open_stage, parse_frames
    from ..io.usd_write import OutputLayer, check_output_path
    from .tiles import TiledMeshes

    if not os.path.exists(input_path):
        raise SubdivInputError(f"{input_path}: no such file")
    stage = open_stage(input_path)
    out_abs = check_output_path(output_path, stage)
    chosen = parse_frames(frames)

    p, rate_of, warnings_ = _read_plan(stage, input_path, prims, chosen, scheme=scheme, rules=rules,
                                       boundary=boundary, all_variants=all_variants, camera=camera,
                                       pixel_error=pixel_error, resolution=resolution, rate=rate,
                                       edge_length=edge_length, depth=depth, device=device)
    tiled_items = _choose_tiled(p, rate_of, warnings_, max_memory, flatten, out_abs, edge_length=edge_length,
                                scheme=scheme, rules=rules, boundary=boundary, depth=depth, quads=quads)
    custom = {"warpSubdiv": {"version": __version__, "command": "tessellate", "source": os.path.basename(input_path),
                             "rate": int(rate) if rate is not None else 0,
                             **({"camera": str(camera), "pixelError": float(pixel_error)} if camera else {}),
                             "edgeLength": float(edge_length) if edge_length is not None else 0.0,
                             "allVariants": bool(all_variants)}}
    layer = OutputLayer(out_abs, stage, custom)
    reports = []
    tiled = TiledMeshes(layer, out_abs, [], max_memory=max_memory, device=device, limit=False, normals=True)
    try:
        out_layout = layout(p)
        for sp, key in zip(p.prims, p.keys):
            target = str(out_layout.homes[key])  # its own path, a prototype's content or a shared mesh
            reports.append(_tessellate_prim(sp, target, layer, warnings_, rate=rate_of[key], edge_length=edge_length,
                                            scheme=scheme, rules=rules, boundary=boundary, depth=depth, quads=quads,
                                            device=device))
            for dst in out_layout.copies[key]:
                layer.copy(out_layout.homes[key], dst)
        out_layout.write(layer)
        out_layout.check(layer, p, reports)
        layer.override_extents_hints(stage, out_layout.hint_roots(p), chosen)
        reports += _write_tiled(tiled, tiled_items)
        layer.commit(flatten=flatten)
        tiled.publish()
    except BaseException:
        layer.discard()
        tiled.discard()
        raise
    return reports, warnings_


def _read_plan(stage, input_path, prims, chosen, *, scheme, rules, boundary, all_variants, camera, pixel_error,
               resolution, rate, edge_length, depth, device):
    """The meshes to tessellate (a skinned mesh as UsdSkel poses it at each time), in refine's plan, with each
    mesh's rate (the camera's per-edge rates where a camera is given) and the meshes' warnings: (plan, rate of
    each mesh key, warnings)."""
    from ..io.usd_read import read_mesh
    from ..io.usd_scene import read_scene
    from .planning import Plan
    from .skinning import Skinning

    skinning = Skinning("bake", chosen)  # a skinned mesh: tessellated as UsdSkel poses it at each time

    def read(prim):
        return skinning.attach(read_mesh(prim, scheme=scheme, rules=rules, boundary=boundary, frames=chosen))

    rates_of: dict = {}  # digest of a mesh's camera rates -> the rates
    level = context = None
    if camera is not None:
        level, context = _camera_rates(stage, camera, pixel_error, resolution, chosen, rates_of, rate, edge_length,
                                       dict(scheme=scheme, rules=rules, boundary=boundary, depth=depth,
                                            device=device))
    elif pixel_error is not None or resolution is not None:
        raise SubdivInputError("pixel_error and resolution are for rates from camera: give camera too",
                               option=("pixel_error", "camera"))
    scene = read_scene(stage, prims, read=read, all_variants=all_variants, where=input_path, level=level,
                       level_context=context)
    p = Plan(input_path, stage, [], [], scene=scene)
    p.left_alone.extend(scene.left_alone)
    for key, sp in scene.units.items():
        if sp is not None:
            p.prims.append(sp)
            p.keys.append(key)
    if not p.prims:
        raise SubdivInputError(f"{input_path}: no subdivision meshes to tessellate"
                               + (f" under {', '.join(prims)}" if prims else ""))
    warnings_ = [f"{sp.path}: {w}" for sp in p.prims for w in sp.warnings]
    rate_of = {key: {"edges": rates_of[scene.levels[key]]} if camera is not None else rate for key in p.keys}
    return p, rate_of, warnings_


def _write_tiled(tiled, items) -> list:
    """Tessellate in tiles and write the meshes of ``items`` (:func:`_choose_tiled`); a report per mesh."""
    import time

    reports = []
    for sp, keywords in items:
        t0 = time.perf_counter()
        _, count, faces, vertices = tiled.write_tessellated([(sp, keywords)])[0]
        options = keywords["options"]
        reports.append(MeshReport(sp.path, options.scheme.value, options.rules.value, sp.mesh.num_faces, faces,
                                  vertices, time.perf_counter() - t0, count))
    return reports


def _prim_options(sp, scheme, rules, boundary):
    """A mesh's tessellation options (float64; a bilinear mesh's linear surface)."""
    from .planning import options_for

    options = options_for(sp, scheme=scheme, rules=rules, boundary=boundary, precision="float64")
    return options.replace(linear=True) if sp.scheme == "bilinear" else options


def _choose_tiled(p, rate_of, warnings_, max_memory, flatten, out_abs, *, edge_length, scheme, rules, boundary,
                  depth, quads) -> list:
    """The meshes of the plan whose tessellation would not fit ``max_memory`` (bytes; None: no limit), taken out
    of the plan: (SubdivPrim, keywords of :func:`warp_subdiv.tessellate_tiled`) each. They are written as the
    tiled bake writes a refined mesh (:class:`~warp_subdiv.usd.tiles.TiledMeshes`): the mesh deactivated, a
    sibling Xform ``<name>_tiles`` of tile meshes (points, faces, normals, ids; bindings and constant primvars
    carried), with a warning; a mesh the tiles cannot write (face-varying or other non-constant primvars, subsets,
    time samples, skinning, instances, variants, shared meshes, flattened output, bilinear) is refused, naming it
    (:func:`~warp_subdiv.usd.tiles.check_tileable`)."""
    import os

    from ..tiled_tessellation import tessellation_fits
    from .tiles import check_tileable, without

    if max_memory is None:
        return []
    chosen, items = [], []
    for i, (sp, key) in enumerate(zip(p.prims, p.keys)):
        if sp.topologies:
            continue  # refused by _tessellate_prim
        options = _prim_options(sp, scheme, rules, boundary)
        keywords = dict(rate=rate_of[key], edge_length=edge_length, quads=quads, options=options,
                        depth=DEFAULT_DEPTH if depth is None else depth)
        try:
            fits, _ = tessellation_fits(sp.mesh, max_memory=max_memory, **keywords)
        except SubdivInputError as exc:
            raise sp.error(exc) from None
        if not fits:
            check_tileable(p, i, flatten=flatten, tessellate=True)
            chosen.append(i)
            items.append((sp, keywords))
            warnings_.append(f"{sp.path}: does not fit max_memory: tessellated in tiles ({os.path.basename(out_abs)}: "
                             f"{sp.prim.GetName()}_tiles, the mesh deactivated)")
    if chosen:
        without(p, chosen)
    return items


def _camera_rates(stage, camera, pixel_error, resolution, frames, rates_of, rate, edge_length, surface_options):
    """read_scene's ``level`` and ``level_context`` for rates from a camera: each composed mesh's per-edge rates
    (:meth:`~warp_subdiv.usd.levels.CameraLevels.edge_rates`), kept in ``rates_of`` under a digest of them that
    becomes part of the mesh's unit."""
    import hashlib

    from ..limit import MAX_RATE, edge_curves
    from .levels import CameraLevels
    from .planning import options_for

    if rate is not None or edge_length is not None:
        raise SubdivInputError("give rate, edge_length or camera, not two of them", option=("camera", "rate"))
    cam = CameraLevels(stage, camera, pixel_error, resolution=resolution, frames=frames)
    depth, device = surface_options.pop("depth"), surface_options.pop("device")

    def level(prim, sp):
        if sp.topologies:
            raise SubdivInputError(f"{sp.path}: its topology changes over time; tessellate takes one topology")
        options = options_for(sp, precision="float64", **surface_options)
        if sp.scheme == "bilinear":
            options = options.replace(linear=True)

        def curves_at(points):
            try:
                return edge_curves(_surface(_with_points(sp.mesh, points), options, depth, device))
            except SubdivInputError as exc:
                raise sp.error(exc) from None

        rates, note = cam.edge_rates(prim, sp, curves_at, MAX_RATE)
        digest = hashlib.sha1(rates.tobytes()).hexdigest()[:16]
        rates_of[digest] = rates
        return digest, f"camera {cam.path} ({note})"

    return level, lambda instance: str(instance.GetPath())


def _tessellate_prim(sp, target, layer, warnings_, *, rate, edge_length, scheme, rules, boundary, depth, quads,
                     device) -> MeshReport:
    """Tessellate one mesh (as read) and write it at ``target``, its path in ``layer``."""
    import time

    from pxr import Sdf, UsdGeom, Vt

    from ..io.usd_stage import DEFAULT
    from ..io.usd_write import extent_of

    T = Sdf.ValueTypeNames
    t0 = time.perf_counter()
    if sp.topologies:
        raise SubdivInputError(f"{sp.path}: its topology changes over time; tessellate takes one topology")
    # bilinear meshes: bilinear patches (quads; a polygon's quad sub-faces, as bilinear refinement splits it)
    options = _prim_options(sp, scheme, rules, boundary)
    linear = sp.scheme == "bilinear"
    mesh = sp.mesh
    if getattr(sp, "skin", None) is not None and sp.skin.mode == "bake":
        mesh = _with_points(mesh, sp.points_at(DEFAULT))  # a skinned mesh: as UsdSkel poses it at the default time
    try:
        surface = _surface(mesh, options, depth, device)
        t = surface.tessellate(rate=rate, edge_length=edge_length, quads=quads)
    except SubdivInputError as exc:
        raise sp.error(exc) from None
    prim = layer.prim(target)
    layer.set(layer.attr(prim, "subdivisionScheme", T.Token, uniform=True), "none")
    layer.set(layer.attr(prim, "points", T.Point3fArray), Vt.Vec3fArray.FromNumpy(t.points.astype(np.float32)))
    layer.set(layer.attr(prim, "faceVertexCounts", T.IntArray), Vt.IntArray.FromNumpy(t.face_vertex_counts))
    layer.set(layer.attr(prim, "faceVertexIndices", T.IntArray), Vt.IntArray.FromNumpy(t.face_vertex_indices))
    corner_face = np.repeat(t.face_base_face.astype(np.int64), t.face_vertex_counts)
    if linear:  # flat patches meet at creases: one normal per face corner, from the corner's own face
        normals = surface.evaluate(corner_face, t.face_uv[:, 0], t.face_uv[:, 1]).normals
    else:
        normals = t.normals
    normals = -normals if sp.orientation == "leftHanded" else normals
    spec = layer.attr(prim, "normals", T.Normal3fArray)
    spec.SetInfo("interpolation", "faceVarying" if linear else "vertex")
    layer.set(spec, Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    layer.set(layer.attr(prim, "extent", T.Float3Array), extent_of(t.points))

    def surface_at(points):  # the surface of other points: the same options, depth and device
        return _surface(_with_points(sp.mesh, points), options, depth, device)

    _write_samples(sp, layer, prim, t, surface, surface_at, linear)
    _block_control_attributes(sp, layer, prim, warnings_)
    if getattr(sp, "skin", None) is not None:
        from .skinning_output import drop_binding

        drop_binding(sp, layer, prim)  # its pose is baked: nothing skins it again
    _write_primvars(sp, layer, prim, t, warnings_, surface, DEFAULT)
    _write_subsets(sp, target, layer, t, surface, warnings_)
    base = layer.attr(prim, "primvars:tessellation:baseFace", T.IntArray, custom=False)
    base.SetInfo("interpolation", UsdGeom.Tokens.uniform)
    layer.set(base, Vt.IntArray.FromNumpy(t.face_base_face))
    uv = layer.attr(prim, "primvars:tessellation:uv", T.TexCoord2fArray, custom=False)
    uv.SetInfo("interpolation", UsdGeom.Tokens.faceVarying)
    layer.set(uv, Vt.Vec2fArray.FromNumpy(t.face_uv.astype(np.float32)))
    return MeshReport(sp.path, options.scheme.value, options.rules.value, len(sp.mesh.face_vertex_counts),
                      t.num_faces, t.num_vertices, time.perf_counter() - t0)


def _write_samples(sp, layer, prim, t, surface, surface_at, linear: bool) -> None:
    """What moves over time: at every selected sample of the points, the same tessellation (edge rates) of the
    points there (``surface_at(points)``): points, normals, extent; velocities and accelerations, the points'
    derivatives, evaluated with the points' weights (:func:`vertex_data`, as refine refines them like the
    points) at the default time and each of their samples, on the surface of the points at that time where
    the points have a sample there (piecewise-smooth rules weigh by the points), else on ``surface``."""
    from pxr import Sdf, Vt

    from ..io.usd_stage import DEFAULT
    from ..io.usd_write import extent_of, vec3f_array
    from .primvars import default_or_sample

    T = Sdf.ValueTypeNames
    corner_face = np.repeat(t.face_base_face.astype(np.int64), t.face_vertex_counts)
    vectors = {name: layer.attr(prim, name, sp.prim.GetAttribute(name).GetTypeName()) for name in sp.point_arrays}

    def write_vectors(when, moving_surface):
        for name, spec in vectors.items():
            if when == DEFAULT or when in sp.point_arrays[name]:
                data = sp.vector_array_at(name, when)
                try:
                    values = vertex_data(moving_surface, data, t.base_face, t.uv)
                except SubdivInputError as exc:
                    raise sp.error(exc) from None
                layer.set(spec, *default_or_sample(when, vec3f_array(values)))

    write_vectors(DEFAULT, surface)
    for when in sp.point_times:
        points = sp.points_at(when)
        try:
            moved = surface_at(points)
            ev = moved.evaluate(t.base_face, t.uv[:, 0], t.uv[:, 1])
            nt = moved.evaluate(corner_face, t.face_uv[:, 0], t.face_uv[:, 1]).normals if linear \
                else ev.normals
        except SubdivInputError as exc:
            raise sp.error(exc) from None
        layer.set(layer.attr(prim, "points", T.Point3fArray), None,
                  [(when, Vt.Vec3fArray.FromNumpy(ev.points.astype(np.float32)))])
        nt = -nt if sp.orientation == "leftHanded" else nt
        layer.set(layer.attr(prim, "normals", T.Normal3fArray), None,
                  [(when, Vt.Vec3fArray.FromNumpy(nt.astype(np.float32)))])
        layer.set(layer.attr(prim, "extent", T.Float3Array), None, [(when, extent_of(ev.points))])
        write_vectors(when, moved)
    for when in sorted({x for times in sp.point_arrays.values() for x in times} - set(sp.point_times)):
        write_vectors(when, surface)


def _block_control_attributes(sp, layer, prim, warnings_) -> None:
    """Block what belongs to the control mesh and is not rewritten for the tessellation: the subdivision
    attributes, every subdiv: tag, authored normals other than the written ``normals`` (with their indices), and
    the attributes the reader found cannot be refined (values that cannot be interpolated, such as int or
    string vertex primvars), these with a warning, as refine blocks them."""
    from pxr import Sdf

    from ..io.usd_read import SUBDIVISION_ATTRIBUTES
    from .primvars import drop_attribute

    usd_prim = sp.prim
    for name in SUBDIVISION_ATTRIBUTES:
        attr = usd_prim.GetAttribute(name)
        layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform)
    for name in sp.subdiv_attributes:
        attr = usd_prim.GetAttribute(name)
        layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform,
                    custom=True)
    for name in sp.authored_normals:
        if name != "normals":
            layer.block(prim, name, usd_prim.GetAttribute(name).GetTypeName())
            if name == "primvars:normals" and usd_prim.GetAttribute(name + ":indices"):
                layer.block(prim, name + ":indices", Sdf.ValueTypeNames.IntArray)
    for name, reason in sp.dropped:
        drop_attribute(sp, layer, prim, name, reason, warnings_)


def _with_points(mesh, points):
    """``mesh`` (topology, creases, corners, concave tags, holes) with other ``points`` and no prescribed normals."""
    from ..mesh import Mesh

    return Mesh(points, mesh.face_vertex_counts, mesh.face_vertex_indices, creases=mesh.creases,
                crease_sharpness=mesh.crease_sharpness, corners=mesh.corners, corner_sharpness=mesh.corner_sharpness,
                concave=mesh.concave, holes=mesh.holes)


def vertex_data(surface, data, faces, uv) -> np.ndarray:
    """The limit of per-control-vertex ``data`` (V, k) at (``faces``, ``uv``): (n, k) float64, by
    :meth:`~warp_subdiv.limit.LimitSurface.evaluate_data` (the data subdivided with the positions' weights, as
    ``refine`` refines vertex primvars)."""
    data = np.asarray(data, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    return surface.evaluate_data(data.reshape(len(data), -1), faces, uv[:, 0], uv[:, 1]).values


def _interpolate(corner_values, corners, weights) -> np.ndarray:
    vals = corner_values[np.maximum(corners, 0)]  # (n, m, k)
    return np.einsum("nm,nmk->nk", weights * (corners >= 0), vals)


def _write_primvars(sp, layer, prim, t, warnings_, surface=None, default_time=None) -> None:
    """Uniform primvars follow their control faces; vertex primvars are evaluated on the limit surface
    (subdivided with the points' weights, as refine refines them), varying ones linearly inside the control
    face at each vertex's (u, v), face-varying ones on the limit surface of their value mesh under the mesh's
    faceVaryingLinearInterpolation (as refine and OpenSubdiv's Bfr; "all" is linear inside the control face) at
    each output corner's (u, v) (written unindexed); constant ones are left as they are; time-sampled ones are
    blocked, with a warning. (Values that cannot be interpolated are not among ``sp.primvars``: the reader lists
    them in ``sp.dropped``, blocked by :func:`_block_control_attributes`.)"""
    from pxr import Sdf

    from ..io.usd_write import vt_array

    V = sp.mesh.num_vertices
    C = len(sp.mesh.face_vertex_indices)
    for pv in sp.primvars:
        if pv.interpolation == "constant":
            continue
        attr = pv.primvar.GetAttr()
        if pv.interpolation == "uniform" and not pv.times:
            values = pv.primvar.ComputeFlattened()
            if values is not None and len(values) == len(sp.mesh.face_vertex_counts) * max(pv.element_size, 1):
                arr = np.asarray(values)
                per_face = arr.reshape(len(sp.mesh.face_vertex_counts), -1) if pv.element_size > 1 else arr
                out = per_face[t.face_base_face].reshape((-1,) + arr.shape[1:])
                spec = layer.attr(prim, pv.name, pv.type_name)
                spec.SetInfo("interpolation", "uniform")
                try:
                    value = type(values).FromNumpy(np.ascontiguousarray(out))
                except (AttributeError, TypeError):
                    value = type(values)(out.tolist())
                layer.set(spec, value)
                if pv.indexed:
                    layer.block(prim, pv.name + ":indices", Sdf.ValueTypeNames.IntArray)
                continue
        why = "not tessellated"
        if pv.interpolation in ("vertex", "varying", "faceVarying") and surface is not None:
            if pv.times:
                why = "time-sampled primvars are not tessellated"
            else:
                fv_index = None
                try:
                    if pv.interpolation == "faceVarying":
                        rows, fv_index = pv.elements(default_time, sp.path)
                        fv_index = np.arange(len(rows)) if fv_index is None else np.asarray(fv_index, np.int64)
                    else:
                        rows = pv.flattened(default_time, sp.path)
                except SubdivInputError as exc:
                    rows, why = None, str(exc)
                want = C if pv.interpolation == "faceVarying" else V
                given = None if rows is None else len(rows) if fv_index is None else len(fv_index)
                if rows is not None and given == want:
                    rows = rows.astype(np.float64)
                    if pv.interpolation == "vertex":
                        out = vertex_data(surface, rows, t.base_face, t.uv)
                    elif pv.interpolation == "varying":
                        corner_rows = rows[np.asarray(sp.mesh.face_vertex_indices, dtype=np.int64)]
                        out = _interpolate(corner_rows, *corner_weights(surface, t.base_face, t.uv))
                    else:  # on the limit surface of the channel's values, under the mesh's interpolation mode
                        nfc = np.repeat(t.face_base_face.astype(np.int64), t.face_vertex_counts)
                        try:
                            out = surface.evaluate_face_varying(rows, fv_index, nfc, t.face_uv[:, 0], t.face_uv[:, 1],
                                                                mode=sp.face_varying_mode).values
                        except SubdivInputError as exc:
                            raise sp.error(exc) from None
                        out = out.reshape(len(out), -1)
                    probe = np.asarray(pv.primvar.GetAttr().Get(default_time) or [])
                    dims = out.shape[1] // max(pv.element_size, 1)
                    value = vt_array(pv.type_name, out.reshape(-1, dims) if dims > 1 else out.reshape(-1),
                                     like=probe.reshape(-1) if probe.size else None)
                    spec = layer.attr(prim, pv.name, pv.type_name, custom=attr.IsCustom())
                    spec.SetInfo("interpolation", pv.interpolation)
                    if pv.element_size > 1:
                        spec.SetInfo("elementSize", pv.element_size)
                    layer.set(spec, value)
                    if pv.indexed:
                        layer.block(prim, pv.name + ":indices", Sdf.ValueTypeNames.IntArray)
                    continue
                if rows is not None:
                    why = f"{given} values for {want} {'corners' if want == C else 'vertices'}"
        warnings_.append(f"{sp.path}: primvar {pv.name} ({pv.interpolation}) is not tessellated ({why}); blocked")
        layer.block(prim, pv.name, attr.GetTypeName(), custom=attr.IsCustom())
        if pv.indexed:
            layer.block(prim, pv.name + ":indices", Sdf.ValueTypeNames.IntArray)


@dataclass
class FaceParents:
    """The control face of every output face (``Tessellation.face_base_face``), as the subset writer reads a
    refinement's face map (``FaceMap.parent``)."""

    parent: np.ndarray


class TessellationMaps:
    """A tessellation as refine's subset writer (:func:`~warp_subdiv.usd.subsets.write_subsets`) reads a
    refinement: ``fmap.parent``, the control face of every output face, and ``edges``, the output edges on
    the control edges (:func:`tessellation_edges`, built on first use), so that face and edge subsets are
    remapped by the same code as refine's."""

    def __init__(self, surface, t):
        self.surface, self.t = surface, t
        self.fmap = FaceParents(np.asarray(t.face_base_face, dtype=np.int64))
        self._edges = None

    @property
    def edges(self):
        if self._edges is None:
            self._edges = tessellation_edges(self.surface, self.t)
        return self._edges


def tessellation_edges(surface, t):
    """The output edges of tessellation ``t`` of ``surface`` that lie on control edges, as a
    :class:`~warp_subdiv.usd.subsets.ControlEdgeMap` (each output edge once, as a (low, high) vertex pair, with
    the control edge it lies on; :func:`_control_side` finds it)."""
    from ..mesh import face_offsets_of, next_corner_of
    from .subsets import ControlEdgeMap

    mesh = surface.mesh
    counts = np.asarray(t.face_vertex_counts, dtype=np.int64)
    ends_a = np.asarray(t.face_vertex_indices, dtype=np.int64)
    nxt = next_corner_of(counts, face_offsets_of(counts))
    ends_b = ends_a[nxt]
    corner_face = np.repeat(np.asarray(t.face_base_face, dtype=np.int64), counts)
    side = np.empty(len(corner_face), dtype=np.int64)
    for lo in range(0, len(side), _EDGE_CHUNK):  # the weights of a chunk of corners at a time (memory)
        hi = min(lo + _EDGE_CHUNK, len(side))
        side[lo:hi] = _control_side(surface, corner_face[lo:hi], t.face_uv[lo:hi], t.face_uv[nxt[lo:hi]])
    offsets = face_offsets_of(np.asarray(mesh.face_vertex_counts, dtype=np.int64))
    corner_edge = np.asarray(mesh.edges.corner_edge, dtype=np.int64)
    on = side >= 0
    edge = corner_edge[offsets[corner_face[on]] + side[on]]
    pairs = np.stack([np.minimum(ends_a[on], ends_b[on]), np.maximum(ends_a[on], ends_b[on])], axis=1)
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    return ControlEdgeMap(mesh, mesh.edges, pairs, edge[first])


#: Output corners whose weights :func:`tessellation_edges` computes at once.
_EDGE_CHUNK = 1 << 18


def _control_side(surface, faces, uv_a, uv_b) -> np.ndarray:
    """For output edges from ``uv_a`` to ``uv_b`` inside control ``faces``: the corner j of the face whose edge
    (corner j to corner j + 1) the output edge lies on, or -1. Both ends are on that side of the face's
    parameter domain where the linear weights of the face's corners (:func:`corner_weights`) are zero at both
    but on corners j and j + 1; every cell of a tessellation is a convex piece of the domain with straight
    sides (a quad, a polygon's quad sub-face, a Loop fan triangle), so the edge between them lies on it too."""
    # the corners either end depends on (exact zeros on a side; both ends' weights have the same columns)
    on = (np.abs(corner_weights(surface, faces, uv_a)[1]) > 1e-12) | (np.abs(corner_weights(surface, faces, uv_b)[1])
                                                                      > 1e-12)
    size = np.asarray(surface.mesh.face_vertex_counts, dtype=np.int64)[faces]
    first = np.argmax(on, axis=1)
    last = on.shape[1] - 1 - np.argmax(on[:, ::-1], axis=1)
    side = np.where(last == first + 1, first, np.where((first == 0) & (last == size - 1), last, -1))
    side[on.sum(axis=1) != 2] = -1
    return side


def _write_subsets(sp, target, layer, t, surface, warnings_) -> None:
    """Face subsets: the output faces whose control face is in the subset; edge subsets: the output edges on
    their control edges; at the default time and every selected time sample (under ``target``, the mesh's path
    in the output layer). A subset naming a face or edge the mesh does not have is blocked, with a warning
    (:func:`~warp_subdiv.usd.subsets.write_subsets`)."""
    from ..io.usd_stage import DEFAULT
    from .subsets import write_subsets

    write_subsets(sp, target, layer, TessellationMaps(surface, t), warnings_, lambda own: [DEFAULT] + list(own),
                  set())
