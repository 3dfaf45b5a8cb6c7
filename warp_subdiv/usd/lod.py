"""Levels of detail as variants: ``refine_usd(..., lod_variants=[0, 1, 2])`` (``refine --lod-variants 0,1,2``)
writes every refined mesh once per level, each inside the variant ``level<N>`` of a variant set
:data:`LOD_VARIANT_SET` on the mesh's refined data, the last level selected.

The variant set lives where the bake writes a mesh's refined data (its unit's home,
:mod:`~warp_subdiv.usd.output_layout`): on the mesh's own path, on a shared refined mesh that identical meshes
reference, or inside a refined prototype that instances reference; so identical meshes and instances are still
written once per level. Copies of the data (a prototype's content reached from another) carry the variant set
with them.

A variant is weaker than local opinions (LIVRPS): in a layer over the input (a sublayer of the output), a mesh
whose refined attributes the input authors in its own layer stack (:func:`local_meshes`) would keep showing its
control mesh whatever variant is selected, and neither a block nor a reference written by the output can
change that (a block is local too and hides the variant; a reference is weaker still). Such a mesh only gets its
levels in a flattened output, which holds every opinion itself and can move the refined ones into the
variants: :func:`merge_levels` builds it from the output flattened once per level (each a plain bake at that
level, checked like any bake). ``flatten`` asks for that output; without it a run where a selected mesh is
local flattens anyway and says so (a run whose meshes all come through arcs stays a layer over the input).
"""
from __future__ import annotations

from pxr import Sdf, Usd

from ..errors import SubdivInputError
from .levels import check_level

#: The variant set of the levels of detail, on every refined mesh (see the module).
LOD_VARIANT_SET = "subdivLOD"


def check_lod_variants(value) -> list:
    """The levels of ``lod_variants`` (a list of integers >= 0, or the text ``0,1,2``), distinct, in the
    order given (the last is the selected variant); SubdivInputError naming the option otherwise."""
    text = value
    if isinstance(value, str):
        try:
            value = [int(v) for v in value.split(",")]
        except ValueError:
            raise SubdivInputError(f"lod_variants must be levels separated by commas (0,1,2), got {text!r}",
                                   option="lod_variants", value=text) from None
    if not isinstance(value, (list, tuple)) or not value:
        raise SubdivInputError(f"lod_variants must be a non-empty list of levels, got {text!r}",
                               option="lod_variants", value=text)
    levels = [check_level(v, "lod_variants") for v in value]
    if len(set(levels)) != len(levels):
        raise SubdivInputError(f"lod_variants lists a level twice: {text!r}", option="lod_variants", value=text)
    return levels


def check_lod_run(lod_variants, **others) -> list:
    """The levels of ``lod_variants`` (:func:`check_lod_variants`), refused beside any of ``others`` (the run's
    options that choose levels per mesh or write elsewhere: camera, max_levels, all_variants, flatten,
    mesh_levels, samples_only) that is set."""
    levels = check_lod_variants(lod_variants)
    for name, value in others.items():
        if value is not None and value is not False:
            raise SubdivInputError(f"lod_variants does not combine with {name}", option=("lod_variants", name))
    return levels


def variant_name(level: int) -> str:
    """The variant that holds level ``level``: ``level<N>``."""
    return f"level{int(level)}"


def lod_path(target, level: int) -> Sdf.Path:
    """Where level ``level`` of the refined data written at ``target`` goes: inside its variant."""
    return Sdf.Path(str(target)).AppendVariantSelection(LOD_VARIANT_SET, variant_name(level))


def declare_variant_set(layer: Sdf.Layer, target, levels) -> None:
    """Name the variant set on the prim spec at ``target`` (its variants were written by :func:`lod_path`) and
    select the last level."""
    spec = layer.GetPrimAtPath(str(target))
    if spec is None:
        return
    if LOD_VARIANT_SET not in spec.variantSetNameList.prependedItems:
        spec.variantSetNameList.prependedItems.append(LOD_VARIANT_SET)
    spec.variantSelections[LOD_VARIANT_SET] = variant_name(levels[-1])


def local_meshes(stage: Usd.Stage, paths) -> list:
    """The mesh paths of ``paths`` that ``stage``'s own layer stack (the input file and its sublayers) authors
    attributes on at the mesh's own path: opinions stronger than any variant the output could write."""
    stack = set(stage.GetLayerStack(includeSessionLayers=False))
    out = []
    for path in paths:
        prim = stage.GetPrimAtPath(str(path))
        if prim and any(spec.layer in stack and spec.path == prim.GetPath() and spec.attributes
                        for spec in prim.GetPrimStack()):
            out.append(str(path))
    return out


def merge_levels(flats: dict, levels) -> Sdf.Layer:
    """One flattened layer with the variant set :data:`LOD_VARIANT_SET` from ``flats`` ({level: the output of a
    bake at that level, flattened}, all of one stage, so they hold the same prims): the layer of the last level
    of ``levels`` (the selected one), where every attribute whose value differs between the levels and every
    prim that exists at some levels only is moved into the variants of the mesh that holds it (the nearest
    Mesh at or above it), each variant holding that level's spec. What is equal at every level stays where it
    is, so each selection composes to exactly that level's flattened bake. A differing attribute outside any
    mesh (an ancestor's ``extentsHint``) keeps the selected level's value."""
    merged = flats[levels[-1]]
    owners: dict = {}  # mesh path -> [(path of a prim or attribute under it that moves, whether a prim)]

    def owner_of(path: Sdf.Path):
        prim = path.GetPrimPath()
        while prim != Sdf.Path.absoluteRootPath:
            spec = merged.GetPrimAtPath(prim)
            if spec is not None and spec.typeName == "Mesh":
                return prim
            prim = prim.GetParentPath()
        return None

    def differs(path: Sdf.Path) -> bool:
        first = None
        for level in levels:
            layer = flats[level]
            spec = layer.GetObjectAtPath(path)
            if spec is None:
                return True
            value = (spec.default if spec.HasInfo("default") else None,
                     [(t, layer.QueryTimeSample(path, t)) for t in layer.ListTimeSamplesForPath(path)])
            if first is None:
                first = value
            elif value != first:
                return True
        return False

    paths: set = set()  # every prim and attribute of any level (a level may hold one the others lack)
    for layer in flats.values():
        layer.Traverse(Sdf.Path.absoluteRootPath,
                       lambda path, layer=layer: paths.add(path) if path.IsPrimPath() or (
                           path.IsPropertyPath() and layer.GetAttributeAtPath(path) is not None) else None)
    for path in sorted(paths):
        if path.IsPrimPath():
            if any(flats[level].GetPrimAtPath(path) is None for level in levels):
                mesh = owner_of(path.GetParentPath())
                if mesh is not None:
                    owners.setdefault(mesh, []).append((path, True))
        elif differs(path):
            mesh = owner_of(path)
            if mesh is not None:
                owners.setdefault(mesh, []).append((path, False))
    for mesh, moved in owners.items():
        # a prim moved whole carries its attributes: drop those listed under it
        prims = [path for path, whole in moved if whole]
        moved = [(path, whole) for path, whole in moved
                 if not any(path != p and path.HasPrefix(p) for p in prims)]
        for level in levels:
            layer = flats[level]
            for path, _ in moved:
                if layer.GetObjectAtPath(path) is None:
                    continue
                dest = path.ReplacePrefix(mesh, lod_path(mesh, level))
                Sdf.CreatePrimInLayer(merged, dest.GetPrimOrPrimVariantSelectionPath())
                if not Sdf.CopySpec(layer, path, merged, dest):
                    raise SubdivInputError(f"could not copy {path} into the variant {variant_name(level)}")
        for path, whole in moved:  # the local specs go: the variants' are the only opinions left
            if whole:
                spec = merged.GetPrimAtPath(path)
                if spec is not None:
                    del spec.nameParent.nameChildren[spec.name]
            else:
                owner = merged.GetPrimAtPath(path.GetPrimPath())
                if owner is not None and path.name in owner.properties:
                    owner.RemoveProperty(owner.properties[path.name])
        declare_variant_set(merged, mesh, levels)
    return merged


__all__ = ["LOD_VARIANT_SET", "check_lod_run", "check_lod_variants", "declare_variant_set", "local_meshes", "lod_path",
           "merge_levels", "variant_name"]
