"""What the refined mesh of a skinned mesh says about skinning (:func:`write_skinning`): with ``skinning="bake"``
or ``"none"`` its binding dropped (:func:`drop_binding`), with ``"keep"`` the refined binding
(:func:`write_kept_binding`).

``skinning="keep"``: the refined mesh stays bound to its skeleton.

Per refined vertex, the joint weights are the refinement of the control vertices' weights: each joint's weight
column is refined like vertex data (the rules the points are refined with, limit values with ``limit``), then the
largest ``k`` weights are kept (``k``: the input's elementSize, or ``max_influences``) and renormalised with
UsdSkel's own :func:`pxr.UsdSkel.NormalizeWeights`; the joint indices follow. Constant (rigid) influences hold for
any topology and are inherited as they are, and so is ``geomBindTransform``. Blend-shape offsets (and those of
their inbetweens, and normal offsets) are refined like points: refinement is linear, so a shape's refined offsets
are exactly the refinement's response to it; its ``pointIndices`` become the refined points those offsets reach.

With ``limit``, the refined points are the limit points of the rest pose, and the weights and blend-shape offsets
are limit values too (the same limit masks): the rest pose and the blend shapes stay exact. No normals are written
on a mesh that stays skinned (:data:`KEPT_NORMALS`): renderers do not skin a ``normals`` attribute alike, and
rest-pose normals on posed points shade wrongly wherever they are used as they are.

Skinning the refined mesh with interpolated weights is not what a renderer draws for the input (it refines the
skinned cage; weights do not commute with refinement): the bake warns once per mesh with the largest deviation
between the two, measured with UsdSkel's own skinning on both sides, over the sampled frames
(:data:`DEVIATION_FRAMES` of them at most, evenly spread). Blend shapes commute with refinement, so the deviation is
the skinning's alone.
"""
from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, UsdSkel, Vt

from ..io.usd_stage import DEFAULT
from ..io.usd_write import vec3f_array
from .primvars import limit_values
from .skinning import blended_points, skinned_points

T = Sdf.ValueTypeNames

#: Joint weight columns refined at once (bounds the memory of meshes bound to many joints).
COLUMNS_AT_ONCE = 64
#: The most frames the deviation of a kept binding is measured at.
DEVIATION_FRAMES = 32


#: What binds a mesh to a skeleton on the refined prim: blocked (attributes) or emptied (relationships) where the
#: binding is dropped.
BINDING_ATTRIBUTES = ("primvars:skel:jointIndices", "primvars:skel:jointWeights", "primvars:skel:geomBindTransform",
                      "skel:joints", "skel:blendShapes")
BINDING_RELATIONSHIPS = ("skel:skeleton", "skel:animationSource", "skel:blendShapeTargets")

#: Why ``normals`` asks for none on a mesh whose refined binding is kept (the run's warning).
KEPT_NORMALS = ("skinning keep: no limit normals written, the refined mesh stays skinned: renderers treat the normals "
                "of a skinned mesh differently (Hydra recomputes them after skinning, UsdSkel.BakeSkinning skins them "
                "by linear blending, others draw them as they are), and normals of the rest pose on posed points "
                "shade wrongly; skinning bake writes the limit normals of every pose")


def stays_skinned(sp) -> bool:
    """Whether the refined mesh of ``sp`` stays bound to its skeleton (``skinning="keep"``)."""
    skin = getattr(sp, "skin", None)
    return skin is not None and skin.mode == "keep" and skin.skeleton is not None


def write_skinning(sp, layer, prim_spec, refinement, warnings: list) -> None:
    """What the refined mesh of ``sp`` says about skinning, in its spec ``prim_spec`` of the output ``layer``:
    nothing for a mesh no skeleton deforms; the binding dropped ("bake", "none": joint influences and blend shapes
    blocked, the skeleton relationships emptied, so that nothing deforms the refined mesh again); with "keep", the
    refined binding (:func:`write_kept_binding`)."""
    skin = getattr(sp, "skin", None)
    if skin is None:
        return
    with skin.lock:
        skin.cache.clear()  # its points are written: the deformed points kept for a second request are not needed
    if stays_skinned(sp):
        write_kept_binding(sp, layer, prim_spec, refinement, warnings)
        return
    drop_binding(sp, layer, prim_spec)


def drop_binding(sp, layer, prim_spec) -> None:
    """Block the joint influences and blend shapes of ``sp`` on its refined prim and empty its skeleton
    relationships (an authored empty target list: the inherited skel:skeleton of a SkelRoot no longer reaches
    it)."""
    src = sp.prim
    for name in BINDING_ATTRIBUTES:
        attr = src.GetAttribute(name)
        if attr and attr.HasAuthoredValue():
            layer.block(prim_spec, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform)
            if name.startswith("primvars:") and src.HasAttribute(name + ":indices"):
                layer.block(prim_spec, name + ":indices", T.IntArray)
    for name in BINDING_RELATIONSHIPS:
        if name == "skel:skeleton" or src.HasRelationship(name):
            rel = (prim_spec.relationships[name] if name in prim_spec.relationships
                   else Sdf.RelationshipSpec(prim_spec, name, custom=False))
            rel.targetPathList.ClearEditsAndMakeExplicit()


def refine_vertex_data(refinement, rows: np.ndarray, limit: bool) -> np.ndarray:
    """Per-control-vertex data (n, d) refined as a vertex primvar is (bilinear meshes linearly, limit values with
    ``limit``), in the order the refined points are written."""
    rows = np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)
    if refinement.sp.scheme == "bilinear":
        return refinement.linear_field(rows)
    out = refinement.refiner.evaluate(rows, normal_control=False)
    return limit_values(refinement.refiner, out) if limit else np.asarray(out)


def refined_influences(refinement, indices: np.ndarray, weights: np.ndarray, k: int, limit: bool = False):
    """(joint indices (N, k) int32, weights (N, k) float32) of the refined vertices: each joint's weight column
    refined, the largest ``k`` kept (in decreasing order), negative ones (rules with negative masks) clipped, and
    renormalised by UsdSkel. ``indices``, ``weights``: the control vertices' (n, elementSize)."""
    n = len(indices)
    joints = np.unique(indices)
    column = np.searchsorted(joints, indices)
    best_w = best_j = None
    for start in range(0, len(joints), COLUMNS_AT_ONCE):
        stop = min(start + COLUMNS_AT_ONCE, len(joints))
        dense = np.zeros((n, stop - start))
        inside = (column >= start) & (column < stop)
        rows = np.nonzero(inside)[0]
        np.add.at(dense, (rows, column[inside] - start), weights[inside])
        refined = refine_vertex_data(refinement, dense, limit)
        ids = np.broadcast_to(joints[start:stop], refined.shape)
        if best_w is not None:
            refined, ids = np.concatenate([best_w, refined], axis=1), np.concatenate([best_j, ids], axis=1)
        keep = min(k, refined.shape[1])
        top = np.argpartition(-refined, keep - 1, axis=1)[:, :keep] if refined.shape[1] > keep else \
            np.broadcast_to(np.arange(keep), refined.shape)
        best_w = np.take_along_axis(refined, top, axis=1)
        best_j = np.take_along_axis(ids, top, axis=1)
    order = np.argsort(-best_w, axis=1, kind="stable")
    best_w = np.clip(np.take_along_axis(best_w, order, axis=1), 0.0, None)
    best_j = np.take_along_axis(best_j, order, axis=1)
    if best_w.shape[1] < k:  # fewer joints than influences: pad with zero weights (joint 0), as UsdSkel does
        pad = k - best_w.shape[1]
        best_w = np.concatenate([best_w, np.zeros((len(best_w), pad))], axis=1)
        best_j = np.concatenate([best_j, np.zeros((len(best_j), pad), dtype=best_j.dtype)], axis=1)
    flat = Vt.FloatArray.FromNumpy(np.ascontiguousarray(best_w, dtype=np.float32).reshape(-1))
    UsdSkel.NormalizeWeights(flat, k)
    return best_j.astype(np.int32), np.asarray(flat, dtype=np.float32).reshape(-1, k)


def write_kept_binding(sp, layer, prim_spec, refinement, warnings: list) -> None:
    """The refined binding of ``sp`` on its refined prim (see the module docstring), and the warning with its
    largest deviation from the baked surface."""
    skin = sp.skin
    bake_limit = refinement.limit
    inf = skin.influences
    k = None
    if inf is not None and inf.interpolation == "vertex":
        k = skin.max_influences or inf.indices.shape[1]
        idx, w = refined_influences(refinement, inf.indices, inf.weights, k, bake_limit)
        for name, values, type_name in (("primvars:skel:jointIndices", Vt.IntArray.FromNumpy(idx.reshape(-1)),
                                         T.IntArray),
                                        ("primvars:skel:jointWeights", Vt.FloatArray.FromNumpy(w.reshape(-1)),
                                         T.FloatArray)):
            spec = layer.attr(prim_spec, name, type_name)
            spec.SetInfo("interpolation", "vertex")
            spec.SetInfo("elementSize", int(k))
            layer.set(spec, values)
            if sp.prim.HasAttribute(name + ":indices"):
                layer.block(prim_spec, name + ":indices", T.IntArray)
        skin.kept = (idx, w)
    if skin.blend_query is not None:
        _write_blend_shapes(sp, layer, prim_spec, refinement, bake_limit)
    deviation = kept_deviation(sp, refinement)
    if deviation is not None:
        dev, at, size = deviation
        when = "the default time" if at == DEFAULT else f"time {at:g}"
        warnings.append(f"{sp.path}: skinning keep: the refined mesh stays bound to {skin.skeleton.GetPath()} with "
                        f"refined weights ({k or 'constant'} influences per point), which approximates what a renderer "
                        f"draws (it refines the skinned cage): largest deviation {dev:.3g} ({100 * dev / size:.2g}% "
                        f"of the mesh's size) at {when}")


def _write_blend_shapes(sp, layer, prim_spec, refinement, limit: bool) -> None:
    """Each blend shape target of ``sp``, refined: offsets (inbetweens', normal offsets too) and pointIndices."""
    api = UsdSkel.BindingAPI(sp.prim)
    stage = sp.prim.GetStage()
    n = len(sp.points_default)
    src_root, dst_root = sp.prim.GetPath(), prim_spec.path
    for target in api.GetBlendShapeTargetsRel().GetTargets():
        shape = UsdSkel.BlendShape(stage.GetPrimAtPath(target))
        ids = shape.GetPointIndicesAttr().Get()
        ids = np.arange(n) if ids is None or len(ids) == 0 else np.asarray(ids, dtype=np.int64)
        arrays = {"offsets": shape.GetOffsetsAttr().Get()}
        if shape.GetNormalOffsetsAttr().HasAuthoredValue():
            arrays["normalOffsets"] = shape.GetNormalOffsetsAttr().Get()
        for inbetween in shape.GetInbetweens():
            name = inbetween.GetAttr().GetName()
            arrays[name] = inbetween.GetOffsets()
            if inbetween.GetNormalOffsetsAttr().HasAuthoredValue():
                arrays[name + ":normalOffsets"] = inbetween.GetNormalOffsets()
        refined = {}
        for name, values in arrays.items():
            dense = np.zeros((n, 3))
            dense[ids] = np.asarray(values, dtype=np.float64).reshape(-1, 3)
            refined[name] = refine_vertex_data(refinement, dense, limit and "ormal" not in name)
        reached = np.flatnonzero(np.any(np.stack([np.any(r != 0, axis=1) for r in refined.values()]), axis=0))
        path = target.ReplacePrefix(src_root, dst_root) if target.HasPrefix(src_root) else target
        spec = layer.prim(str(path))
        idx_spec = layer.attr(spec, "pointIndices", T.IntArray, uniform=True)
        layer.set(idx_spec, Vt.IntArray.FromNumpy(reached.astype(np.int32)))
        for name, values in refined.items():
            attr = shape.GetPrim().GetAttribute(name)
            out = layer.attr(spec, name, attr.GetTypeName(), uniform=attr.GetVariability() == Sdf.VariabilityUniform,
                             custom=attr.IsCustom())
            if name.startswith("inbetweens:") and not name.endswith(":normalOffsets"):
                weight = attr.GetMetadata("weight")
                if weight is not None:
                    out.SetInfo("weight", weight)
            layer.set(out, vec3f_array(values[reached]))


def _mesh_order(skin):
    """The skeleton's joint of each of the mesh's joints (its skel:joints), or None where the orders agree."""
    skel_joints = list(skin.skel_query.GetJointOrder())
    joints = skin.influences.joints
    if joints == skel_joints:
        return None
    where = {j: i for i, j in enumerate(skel_joints)}
    return np.array([where[j] for j in joints], dtype=np.int64)


def kept_deviation(sp, refinement):
    """(largest distance, time, the mesh's size) between the baked surface (the refined skinned cage) and UsdSkel's
    skinning of the refined mesh with the kept binding, over the sampled frames; None for a mesh without varying
    joint influences (blend shapes and rigid influences commute with refinement)."""
    skin = sp.skin
    kept = getattr(skin, "kept", None)
    if kept is None:
        return None
    idx, w = kept
    k = idx.shape[1]
    times = list(skin.times) or [DEFAULT]
    if len(times) > DEVIATION_FRAMES:
        times = [times[i] for i in np.linspace(0, len(times) - 1, DEVIATION_FRAMES).round().astype(int)]
    flat_idx = Vt.IntArray.FromNumpy(idx.reshape(-1))
    flat_w = Vt.FloatArray.FromNumpy(w.reshape(-1))
    order = _mesh_order(skin)
    worst, at, size = 0.0, times[0], 0.0
    for t in times:
        baked, _ = refinement.positions(skinned_points(sp, t, space="skeleton"))
        blended = blended_points(sp, t)
        refined, _ = refinement.positions(blended)
        pts = Vt.Vec3fArray.FromNumpy(np.asarray(refined, dtype=np.float32))
        xforms = skin.skel_query.ComputeSkinningTransforms(t)
        if order is not None:  # the skeleton's transforms in the mesh's joint order
            xforms = Vt.Matrix4dArray.FromNumpy(np.asarray(xforms)[order])
        bind = skin.skinning_query.GetGeomBindTransform(t) or Gf.Matrix4d(1)
        UsdSkel.SkinPoints(skin.method, bind, xforms, flat_idx, flat_w, k, pts)
        dist = float(np.max(np.linalg.norm(np.asarray(pts, dtype=np.float64) - baked, axis=1)))
        size = max(size, float(np.max(np.ptp(baked, axis=0))))
        if dist > worst:
            worst, at = dist, t
    return worst, at, size or 1.0


__all__ = ["KEPT_NORMALS", "stays_skinned",
           "BINDING_ATTRIBUTES", "BINDING_RELATIONSHIPS", "write_skinning", "drop_binding", "refine_vertex_data",
           "refined_influences", "write_kept_binding", "kept_deviation", "COLUMNS_AT_ONCE", "DEVIATION_FRAMES"]
