"""Levels of detail as variants: ``refine_usd(..., lod_variants=[0, 1, 2])`` (``refine --lod-variants 0,1,2``)
writes every refined mesh once per level, each inside the variant ``level<N>`` of a variant set
:data:`LOD_VARIANT_SET` on the mesh's refined data, the last level selected.

The variant set lives where the bake writes a mesh's refined data (its unit's home,
:mod:`~warp_subdiv.usd.output_layout`): on the mesh's own path, on a shared refined mesh that identical meshes
reference, or inside a refined prototype that instances reference; so identical meshes and instances are still
written once per level. Copies of the data (a prototype's content reached from another) carry the variant set
with them.

A variant is weaker than local opinions: the input layer (a sublayer of the output) must not hold the mesh's
refined attributes locally, i.e. the mesh must come to the shot through an arc (a reference, payload, instance
or inherited class: the usual asset structure). Where the input authors a mesh in its own layer stack the
output's check finds that the mesh does not compose to its refined faces and says so.
"""
from __future__ import annotations

from pxr import Sdf

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


__all__ = ["LOD_VARIANT_SET", "check_lod_run", "check_lod_variants", "declare_variant_set", "lod_path", "variant_name"]
