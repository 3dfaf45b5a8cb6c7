"""USD value clips over the chunk layers of one refinement: a distributed bake's frame chunks and the layers
that ``warp-subdiv stitch`` assembles (:mod:`warp_subdiv.usd.distributed`).

:func:`stitch_clips` authors one clip set per animated mesh: the chunks' time-invariant content goes into a
topology layer, each clip set gets a manifest of the attributes its chunks sample.
"""
from __future__ import annotations

import os

from pxr import Sdf, Usd, UsdUtils, Vt

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


def stitch_clips(output_layer: Sdf.Layer, folder: str, clips: dict, topology_sources: list) -> list:
    """Author USD value clips in ``output_layer``: ``clips`` maps a prim path (the clip set's prim) to its
    chunks, [(file, start, end)] in time order. Writes into ``folder`` the topology layer (everything the
    chunks hold that is not time-sampled, from ``topology_sources``: UsdUtils.StitchClipsTopology, the first
    chunk's defaults winning) and one manifest per clip set (UsdUtils.StitchClipsManifest); returns the
    topology layer's path (None when there are no clips), for the caller to sublayer.

    Each clip set's ``active`` switches to chunk k at its start and ``times`` maps [start, end] of chunk k
    onto itself; chunk layers may carry any stage time codes (a ``--frames`` run copies the input's)."""
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
    topo.Save()
    stage = Usd.Stage.Open(output_layer)
    stage.SetEditTarget(Usd.EditTarget(output_layer))
    for n, (path, chunks) in enumerate(sorted(clips.items())):
        files = [c[0] for c in chunks]
        manifest_path = os.path.join(folder, f"manifest.{n:04d}.usdc")
        manifest = Sdf.Layer.CreateNew(manifest_path)
        UsdUtils.StitchClipsManifest(manifest, topo, files, Sdf.Path(path))
        prim = stage.OverridePrim(path)
        api = Usd.ClipsAPI(prim)
        api.SetClipAssetPaths(Sdf.AssetPathArray([relative_asset_path(f, anchor) for f in files]))
        api.SetClipPrimPath(path)
        api.SetClipActive(Vt.Vec2dArray([(start, k) for k, (_, start, _) in enumerate(chunks)]))
        times = []
        for _, start, end in chunks:
            times += [(start, start), (end, end)]
        api.SetClipTimes(Vt.Vec2dArray(times))
        api.SetClipManifestAssetPath(Sdf.AssetPath(relative_asset_path(manifest_path, anchor)))
    del stage
    return topo_path


__all__ = ["animated", "clip_range", "stitch_clips"]
