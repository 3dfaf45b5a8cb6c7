"""What a refined layer records about the run that wrote it, in its ``customLayerData["warpSubdiv"]``.

The record names the input, the meshes refined and every option that decides the refined values, as the
meshes resolved them (``boundary=None`` and the file's boundary rule record the same boundary), so that
layers of one refinement can be told from layers of another: ``warp-subdiv stitch`` assembles only chunks
whose records agree on every key of :data:`RESULT_KEYS` (:func:`check_same_refinement`). Chunks of one
refinement differ only in their frames.
"""
from __future__ import annotations

import hashlib
import os

from pxr import Vt

from ..errors import SubdivInputError
from ..io.usd_stage import format_frames
from ..version import __version__
from .order import resolved_vertex_order
from .planning import Plan

#: The keys of the record that decide the refined values, and the option each one comes from (for messages).
RESULT_KEYS = {
    "levels": "levels", "prims": "prims", "schemes": "scheme", "rules": "rules", "boundaries": "boundary",
    "precisions": "precision", "vertexOrders": "vertex order", "semiSharp": "semi-sharp", "limitPoints": "limit",
    "normals": "normals", "allVariants": "all variants", "meshOptions": "the meshes' refinement options",
    "meshLevels": "the meshes' levels", "lodVariants": "lod variants",
    "skinning": "skinning",
}


def _strings(values) -> Vt.StringArray:
    return Vt.StringArray(sorted(set(values)))


def options_digest(p: Plan, vertex_order: str) -> str:
    """A digest of every mesh's refinement options (the file's flatness, normal strength, triangle rule too)
    and vertex order: equal for two runs that refine the meshes alike."""
    rows = [(sp.path, sorted(o.as_dict().items()), resolved_vertex_order(vertex_order, o))
            for sp, o in zip(p.prims, p.options)]
    return hashlib.sha256(repr(rows).encode()).hexdigest()


def layer_record(p: Plan, levels: int, *, limit: bool, normals: bool, semi_sharp: str, vertex_order: str,
                 all_variants: bool, flatten: bool, frames=None, skinning: str = "bake",
                 max_influences=None, lod_variants=None) -> dict:
    """The ``customLayerData`` of a layer that refines the meshes of plan ``p``: ``{"warpSubdiv": {...}}``
    (the version, the input's file name, the frames where given, and the keys of :data:`RESULT_KEYS`).

    ``levels`` is the run's default level; ``meshLevels`` maps every composed mesh refined to its own level
    (:attr:`Plan.level_sources`: ``subdiv:levels``, a camera, ``max_levels``), so chunks whose meshes were
    refined to other levels are told apart."""
    record = {
        "version": __version__, "levels": int(levels), "source": os.path.basename(p.input),
        "prims": Vt.StringArray([sp.path for sp in p.prims]),
        "rules": _strings(sp.rules for sp in p.prims), "schemes": _strings(sp.scheme for sp in p.prims),
        "boundaries": _strings(o.boundary.value for o in p.options),
        "precisions": _strings(o.precision.value for o in p.options),
        "vertexOrders": _strings(resolved_vertex_order(vertex_order, o) for o in p.options),
        "semiSharp": str(semi_sharp), "limitPoints": bool(limit), "normals": bool(normals),
        "allVariants": bool(all_variants), "meshOptions": options_digest(p, vertex_order),
        "flattened": bool(flatten),
        "meshLevels": {path: int(level) for path, (level, _) in sorted(p.level_sources.items())},
        # what became of meshes bound to a skeleton (a keep's influence count too)
        "skinning": str(skinning) + ("" if max_influences is None else f":{int(max_influences)}"),
    }
    if frames is not None:
        record["frames"] = format_frames(frames)
    if lod_variants:
        record["lodVariants"] = Vt.IntArray([int(v) for v in lod_variants])
    return {"warpSubdiv": record}


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return list(value) if isinstance(value, (Vt.StringArray, Vt.IntArray)) else value


def check_same_refinement(records) -> None:
    """Refuse layers that do not come from one refinement: ``records`` is [(layer path, its warpSubdiv record)];
    a SubdivInputError names the first key of :data:`RESULT_KEYS` on which a layer differs from the first one,
    with both layers and both values (a key a layer does not record: written by an older warp-subdiv)."""
    (first_path, first), rest = records[0], records[1:]
    for path, record in rest:
        for key, option in RESULT_KEYS.items():
            mine, theirs = _plain(record.get(key)), _plain(first.get(key))
            if mine != theirs:
                def shown(value):
                    return "not recorded" if value is None else repr(value)

                raise SubdivInputError(f"{path}: {option} differs from {first_path}'s ({shown(mine)} against "
                                       f"{shown(theirs)}); chunks must come from one refinement",
                                       option=key, value=mine)


__all__ = ["RESULT_KEYS", "check_same_refinement", "layer_record", "options_digest"]
