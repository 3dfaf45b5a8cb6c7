"""USD value clips over the chunk layers of one refinement: a distributed bake's frame chunks and the layers
that ``warp-subdiv stitch`` assembles (:mod:`warp_subdiv.usd.distributed`).

:func:`stitch_clips` authors one clip set per animated mesh: the chunks' time-invariant content goes into a
topology layer, each clip set gets a manifest of the attributes its chunks sample.
"""
from __future__ import annotations

import os

from pxr import Sdf, Usd, UsdUtils, Vt

from ..io.usd_read import TOPOLOGY_ATTRIBUTES
from ..io.usd_write import relative_asset_path


def clip_range(layer: Sdf.Layer, frames) -> tuple:
    """(start, end) stage times a chunk covers: its frames, its own samples where an end is open."""
    samples = layer.ListAllTimeSamples()
    lo = frames[0] if frames and frames[0] is not None else (min(samples) if samples else 0.0)
    hi = frames[1] if frames and frames[1] is not None else (max(samples) if samples else lo)
    return float(lo), float(hi)


def animated(layer: Sdf.Layer, path: str) -> bool:
    """Whether ``layer`` holds time samples at or under ``path``."""
    found = []

    def visit(p):
        if not found and p.IsPropertyPath() and layer.GetNumTimeSamplesForPath(p):
            found.append(p)

    spec = layer.GetPrimAtPath(path)
    if spec is not None:
        layer.Traverse(spec.path, visit)
    return bool(found)


def stitch_clips(output_layer: Sdf.Layer, folder: str, clips: dict, topology_sources: list,
                 input_stage: Usd.Stage) -> list:
    """Author USD value clips in ``output_layer``: ``clips`` maps a prim path (the clip set's prim, a refined
    mesh) to its chunks, [(file, start, end)] in time order, neighbours sharing their boundary sample. Writes
    into ``folder`` the topology layer (everything the chunks hold that is not time-sampled, from
    ``topology_sources``: UsdUtils.StitchClipsTopology, the first chunk's defaults winning) and one manifest
    per clip set (UsdUtils.StitchClipsManifest); returns the topology layer's path (None when there are no
    clips), for the caller to sublayer.

    Each clip set's ``active`` switches to chunk k at its start; no ``times`` are authored, so each chunk is
    read at the stage's own times (a ``--frames`` run writes the input's time codes). Times that map the
    boundary of two chunks twice would make USD add a sample just before it (a jump there), which flattening
    writes into the output. An attribute that a chunk samples at a boundary only because its range ends
    there (the input ``input_stage`` samples it elsewhere), or that a chunk holds no samples of, is taken out of
    the clips (:func:`merged_attributes`) and written into the topology layer with the chunks' samples at the
    input's times (:func:`merge_samples`), so that the output has exactly the input's samples."""
    if not clips:
        return None
    anchor = os.path.dirname(output_layer.realPath or output_layer.identifier)
    topo_path = os.path.join(folder, "topology.usdc")
    topo = Sdf.Layer.CreateNew(topo_path)
    UsdUtils.StitchClipsTopology(topo, [f for f in topology_sources])
    topo.subLayerPaths.clear()
    topo.customLayerData = {}
    for key in ("startTimeCode", "endTimeCode"):
        topo.pseudoRoot.ClearInfo(key)
    stage = Usd.Stage.Open(output_layer)
    stage.SetEditTarget(Usd.EditTarget(output_layer))
    for n, (path, chunks) in enumerate(sorted(clips.items())):
        files = [c[0] for c in chunks]
        manifest_path = os.path.join(folder, f"manifest.{n:04d}.usdc")
        manifest = Sdf.Layer.CreateNew(manifest_path)
        UsdUtils.StitchClipsManifest(manifest, topo, files, Sdf.Path(path))
        layers = [Sdf.Layer.FindOrOpen(f) for f in files]
        starts = [start for _, start, _ in chunks]
        for attr, own in merged_attributes(manifest, layers, starts, input_stage, path).items():
            merge_samples(topo, attr, layers, starts, own)
            spec = manifest.GetAttributeAtPath(attr)
            spec.owner.RemoveProperty(spec)  # the clips no longer provide it
        manifest.Save()
        prim = stage.OverridePrim(path)
        api = Usd.ClipsAPI(prim)
        api.SetClipAssetPaths(Sdf.AssetPathArray([relative_asset_path(f, anchor) for f in files]))
        api.SetClipPrimPath(path)
        api.SetClipActive(Vt.Vec2dArray([(start, k) for k, start in enumerate(starts)]))
        api.SetClipManifestAssetPath(Sdf.AssetPath(relative_asset_path(manifest_path, anchor)))
    topo.Save()
    del stage
    return topo_path


#: Attributes of a refined mesh written at every time sample of its points, whatever the input samples of the
#: same name (the refined extent, normals and extentsHint follow the refined points).
FOLLOW_POINTS = ("points", "extent", "normals", "extentsHint")


def own_times(input_stage: Usd.Stage, mesh: str, attr: Sdf.Path):
    """The times at which a single bake samples attribute ``attr`` of the refined ``mesh`` (a path at or under
    it), as a set of the input's time samples, or None where every chunk boundary is one of them or the input
    does not tell: those of the input attribute of the same path and of its indices (or values), and those of
    the mesh's topology where it is time-sampled (a refined mesh is written again where its topology
    changes)."""
    name, at_mesh = attr.name, str(attr.GetPrimPath()) == mesh
    prim = input_stage.GetPrimAtPath(attr.GetPrimPath())
    mesh_prim = input_stage.GetPrimAtPath(mesh)
    if not prim or not mesh_prim or (at_mesh and name in FOLLOW_POINTS):
        return None
    topology = [a for a in (mesh_prim.GetAttribute(n) for n in TOPOLOGY_ATTRIBUTES) if a and a.GetNumTimeSamples()]
    sources = []
    if not (at_mesh and name in TOPOLOGY_ATTRIBUTES):
        pair = name[:-len(":indices")] if name.endswith(":indices") else name + ":indices"
        sources = [a for a in (prim.GetAttribute(name), prim.GetAttribute(pair)) if a and a.GetNumTimeSamples()]
    if not sources and not topology:
        return None
    return {t for a in sources + topology for t in a.GetTimeSamples()}


def merged_attributes(manifest: Sdf.Layer, layers, starts, input_stage: Usd.Stage, mesh: str) -> dict:
    """The attributes of ``manifest`` that value clips would not read with the input's time samples: attribute
    path -> its own times (:func:`own_times`). Those that a chunk samples at its start only because its range
    starts there (a value held or interpolated from the input's samples around it: a clip reports it as a
    sample), and those a chunk holds no samples of (refined at its default only, as over a range in which the
    topology does not change: USD would interpolate from the clip's start to the next clip's first sample).
    ``layers``: the chunks in time order, ``starts``: their starts."""
    found = {}

    def visit(path):
        if not path.IsPropertyPath():
            return
        times = [set(layer.ListTimeSamplesForPath(path)) for layer in layers]
        lacking = any(not t for t in times)
        starts_sampled = [start for t, start in zip(times[1:], starts[1:]) if start in t]
        if not lacking and not starts_sampled:
            return
        own = own_times(input_stage, mesh, path)
        if own is not None and (lacking or any(start not in own for start in starts_sampled)):
            found[path] = own

    manifest.Traverse(Sdf.Path(mesh), visit)
    return found


def merge_samples(topo: Sdf.Layer, attr: Sdf.Path, layers, starts, own: set) -> None:
    """Write into ``topo`` the samples of ``attr`` at the times ``own`` says the input has, each from the chunk
    whose range holds it (from its start to the next chunk's; the first chunk's from before, the last one's to
    after): a chunk's samples (not its start where that is no time of ``own``), or its default at the times of
    ``own`` in its range where it holds no samples."""
    spec = topo.GetAttributeAtPath(attr)
    if spec is None:
        source = next(layer.GetAttributeAtPath(attr) for layer in layers if layer.GetAttributeAtPath(attr))
        owner = Sdf.CreatePrimInLayer(topo, attr.GetPrimPath())
        spec = Sdf.AttributeSpec(owner, attr.name, source.typeName, source.variability, source.custom)
    lows = [float("-inf")] + list(starts[1:])
    highs = list(starts[1:]) + [float("inf")]
    for k, (layer, lo, hi) in enumerate(zip(layers, lows, highs)):
        times = layer.ListTimeSamplesForPath(attr)
        if times:
            for t in times:
                if lo <= t < hi and (k == 0 or t != starts[k] or t in own):
                    topo.SetTimeSample(attr, t, layer.QueryTimeSample(attr, t))
            continue
        chunk_spec = layer.GetAttributeAtPath(attr)
        if chunk_spec is not None and chunk_spec.HasDefaultValue():
            for t in sorted(own):
                if lo <= t < hi:
                    topo.SetTimeSample(attr, t, chunk_spec.default)


__all__ = ["FOLLOW_POINTS", "animated", "clip_range", "merge_samples", "merged_attributes", "own_times",
           "stitch_clips"]
