"""Meshes bound to a UsdSkel skeleton (skinned meshes, blend shapes): what the bake refines for them.

A renderer subdivides a skinned mesh *after* skinning: at each time it deforms the control points (blend shapes,
then linear-blend or dual-quaternion skinning, as ``skel:skinningMethod`` says) and refines the deformed cage.
Refining the rest pose and skinning the refined mesh with interpolated weights is a different surface (weights do
not commute with refinement). The bake offers three treatments, the run's ``skinning`` option:

* ``"bake"`` (the default): at every time the pose can change (the samples of the animation's joint transforms
  and blend-shape weights, of the mesh's points and joint influences, and of the transforms between the skeleton
  and the mesh, as ``frames`` selects them) the control points are deformed by usd-core's UsdSkel itself
  (:class:`pxr.UsdSkel.BlendShapeQuery`, :meth:`pxr.UsdSkel.SkinningQuery.ComputeSkinnedPoints`), brought from
  the skeleton's space into the mesh's own (as :func:`pxr.UsdSkel.BakeSkinning` does) and refined with the
  topology built once. Authored ``velocities`` are the pose's, per second (:func:`pose_velocities`: differences
  of the deformed points between the neighbouring times of the pose, scaled by the stage's timeCodesPerSecond);
  authored ``accelerations`` are dropped with a warning. The refined mesh no longer binds the skeleton
  (:func:`~warp_subdiv.usd.skinning_output.write_skinning` blocks its joint
  influences, blend shapes and skeleton binding), so nothing skins it twice; the skeleton and its animation stay
  for whatever else they drive.
* ``"keep"``: the rest pose is refined and the refined mesh stays bound: each joint's weight column is refined
  like vertex data, the largest ``k`` weights of each refined vertex are kept and renormalised (``k``: the
  input's elementSize, or ``max_influences``), blend-shape offsets are refined (refinement is linear, so they are
  exact) and reach the refined vertices they move. An approximation of what a renderer draws: the bake warns with
  the largest deviation from the baked surface over the sampled frames.
* ``"none"``: the rest pose is refined and the binding dropped, with a warning.

:class:`Skinning` is a run's UsdSkel state; its :meth:`~Skinning.attach` turns a mesh as read
(:class:`~warp_subdiv.io.usd_read.SubdivPrim`) into a :class:`SkinnedPrim` whose ``points_at`` gives the deformed
points, so that every path of the bake (threads refining ahead, batches, the distributed bake's frame chunks)
refines them without knowing about skeletons.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field, fields

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdSkel, Vt

from ..errors import SubdivInputError
from ..io.usd_read import SubdivPrim, read_mesh
from ..io.usd_scene import skinned as is_bound
from ..io.usd_stage import DEFAULT, times_for_frames

T = Sdf.ValueTypeNames

#: The treatments of skinned meshes (the bake's ``skinning`` option).
SKINNING_MODES = ("bake", "keep", "none")

#: The joint-influence primvars of UsdSkelBindingAPI (read by the skinning, never refined as plain primvars).
INFLUENCE_PRIMVARS = ("primvars:skel:jointIndices", "primvars:skel:jointWeights")

#: Why a skinned mesh inside an instance is not baked (the error of ``skinning="bake"``, ``info``'s note).
INSTANCE_REFUSAL = "each instance may be posed by its own animation, so baking it would take the instance apart"

#: Weight sums farther than this from one are reported (UsdSkel skins with the weights as they are).
WEIGHT_SUM_TOLERANCE = 1e-4

#: Skinned control points of one mesh kept for a second request (a worker refining ahead, or a batch of small
#: meshes, asks first, the writer then), the oldest dropped first beyond this; the writer drops the rest once it
#: has written the mesh (:func:`~warp_subdiv.usd.skinning_output.write_skinning`).
CACHE_BYTES = 64 << 20


def check_skinning(value) -> str:
    """``value`` if it is one of :data:`SKINNING_MODES`, else a SubdivInputError naming the option."""
    if value not in SKINNING_MODES:
        raise SubdivInputError(f"skinning must be one of {', '.join(SKINNING_MODES)}, got {value!r}",
                               option="skinning", value=value)
    return value


def check_max_influences(value, mode: str = "keep"):
    """``value`` if it is None or an integer >= 1 and ``mode`` (the run's skinning) is "keep", which it sizes."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1):
        raise SubdivInputError(f"max_influences must be an integer >= 1, got {value!r}", option="max_influences",
                               value=value)
    if value is not None and mode != "keep":
        raise SubdivInputError(f"max_influences applies to skinning keep (the refined joint influences), not to "
                               f"skinning {mode}", option="max_influences", value=value)
    return value


@dataclass
class Influences:
    """The joint influences of a mesh as authored and checked: ``indices`` and ``weights`` (points or 1, k)
    for vertex or constant interpolation, ``joints`` the joint order they index (the mesh's ``skel:joints``, else
    the skeleton's)."""

    indices: np.ndarray
    weights: np.ndarray
    interpolation: str
    joints: list


@dataclass
class SkinBinding:
    """How one mesh is skinned: its skeleton, the UsdSkel queries, the treatment and what it needs."""

    mode: str
    skeleton: Usd.Prim | None
    skel_query: object = None  # UsdSkel.SkeletonQuery
    skinning_query: object = None  # UsdSkel.SkinningQuery
    blend_query: object = None  # UsdSkel.BlendShapeQuery, or None without blend shapes
    animation: Usd.Prim | None = None
    influences: Influences | None = None
    method: str = "classicLinear"
    times: list = field(default_factory=list)  # the selected times the pose may change at
    all_times: list = field(default_factory=list)  # every time the pose may change at (velocities' neighbours)
    time_codes_per_second: float = 24.0  # the stage's (velocities are per second)
    refused: str | None = None  # why "bake" does not apply (info describes such a mesh instead of refusing it)
    max_influences: int | None = None  # "keep": joints per refined vertex (None: the input's elementSize)
    kept: tuple | None = None  # "keep": the refined (joint indices, weights) written
    lock: object = field(default_factory=threading.Lock, repr=False)
    cache: dict = field(default_factory=dict, repr=False)  # time -> skinned control points (float32)


@dataclass
class SkinnedPrim(SubdivPrim):
    """A mesh bound to a skeleton, as the bake refines it: with ``skinning="bake"`` its points at a time are the
    control points as UsdSkel deforms them there, in the mesh's own space, and its :attr:`point_times` are the
    times the pose may change; with "keep" and "none" they are the rest points, as read."""

    skin: SkinBinding | None = None

    @property
    def baked(self) -> bool:
        """Whether this mesh's pose is baked (``skinning="bake"``, not refused)."""
        return self.skin is not None and self.skin.mode == "bake" and self.skin.refused is None

    def points_at(self, time) -> np.ndarray:
        if not self.baked:
            return super().points_at(time)
        return self._check_rows(skinned_points(self, time), "points", time)

    def vector_array_at(self, name: str, time) -> np.ndarray:
        """Velocities of a baked pose are the pose's (:func:`pose_velocities`); else as authored."""
        if not self.baked or name != "velocities":
            return super().vector_array_at(name, time)
        return self._check_rows(pose_velocities(self, time), name, time)


class Skinning:
    """A run's UsdSkel state (one :class:`pxr.UsdSkel.Cache` per stage, populated on first use) and treatment
    (``mode``, one of :data:`SKINNING_MODES`) of the meshes bound to a skeleton. ``frames``: the bake's time
    range; ``max_influences``: joints per refined vertex with "keep"; ``pose_instances``: pose skinned meshes
    inside instances (a preview draws each) instead of refusing to bake them; ``describe_instances``: read their
    binding and say why "bake" is refused there (:attr:`SkinBinding.refused`, ``info``) instead of raising."""

    def __init__(self, mode: str = "bake", frames=None, max_influences=None, *, pose_instances: bool = False,
                 describe_instances: bool = False):
        self.mode = check_skinning(mode)
        self.pose_instances = pose_instances  # pose meshes inside instances (a preview) rather than refuse them
        self.describe_instances = describe_instances  # describe (info) rather than refuse them
        self.frames = frames
        self.max_influences = check_max_influences(max_influences, self.mode)
        self._caches: dict = {}  # id(stage) -> (stage, UsdSkel.Cache, the SkelRoots populated)
        self._lock = threading.Lock()

    def cache_of(self, prim: Usd.Prim):
        """The UsdSkel.Cache of ``prim``'s stage, populated for the SkelRoot above ``prim`` (each root once)."""
        stage, root = prim.GetStage(), UsdSkel.Root.Find(prim)
        with self._lock:
            held = self._caches.get(id(stage))
            if held is None or held[0] is not stage:
                held = self._caches[id(stage)] = (stage, UsdSkel.Cache(), set())
            _, cache, populated = held
            if root.GetPath() not in populated:
                cache.Populate(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
                populated.add(root.GetPath())
            return cache

    def attach(self, sp: SubdivPrim | None) -> SubdivPrim | None:
        """The mesh ``sp`` as the bake refines it: itself when no skeleton deforms it, else a :class:`SkinnedPrim`
        (see the module docstring). Its joint influences leave its primvars (they are the skinning's); a binding
        UsdSkel ignores (no SkelRoot above the mesh, influences without a skeleton) is dropped with a warning.
        Errors name the prim and attribute: an animation that is not a SkelAnimation or whose arrays do not fit
        its joints, joint indices outside the joints, elementSizes that differ, blend shapes that do not fit."""
        if sp is None or not is_bound(sp.prim):
            return sp
        prim = sp.prim
        if not any(_authored(prim, name) for name in INFLUENCE_PRIMVARS + ("skel:blendShapes",)):
            return sp  # the binding API without joint influences or blend shapes: UsdSkel deforms nothing
        kept = [pv for pv in sp.primvars if pv.name not in INFLUENCE_PRIMVARS]
        dropped = [(n, r) for n, r in sp.dropped if n not in INFLUENCE_PRIMVARS]
        out = SkinnedPrim(**{f.name: getattr(sp, f.name) for f in fields(SubdivPrim)})
        out.primvars, out.dropped, out.warnings = kept, dropped, list(sp.warnings)
        out.point_arrays, out.stand_in_defaults = dict(sp.point_arrays), set(sp.stand_in_defaults)
        skeleton = UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
        if not skeleton:
            out.skin = SkinBinding("none", None)
            out.warnings.append("joint influences or blend shapes without a bound skeleton (skel:skeleton): UsdSkel "
                                "does not deform this mesh; they are dropped and its points refined as they are")
            return out
        if not UsdSkel.Root.Find(prim):
            out.skin = SkinBinding("none", skeleton.GetPrim())
            out.warnings.append(f"bound to {skeleton.GetPath()} but not under a SkelRoot: UsdSkel does not deform "
                                "this mesh; the binding is dropped and its points refined as they are")
            return out
        if sp.topologies:
            raise SubdivInputError(f"{sp.path}: faceVertexCounts / faceVertexIndices change over time on a mesh "
                                   f"bound to {skeleton.GetPath()}; UsdSkel skins a fixed set of points")
        refused = None
        if self.mode == "bake" and not self.pose_instances and (prim.IsInstanceProxy() or prim.IsInPrototype()):
            if not self.describe_instances:
                raise SubdivInputError(
                    f"{sp.path}: a skinned mesh inside an instance: {INSTANCE_REFUSAL}; bake with skinning keep (the "
                    "refined prototype stays skinned) or none, or make the instance not instanceable",
                    option="skinning", value="bake")
            refused = (f"bake refused inside an instance ({INSTANCE_REFUSAL}): use keep (the refined prototype stays "
                       "skinned) or none, or make the instance not instanceable")
        if self.mode == "none":  # the binding is dropped as it is, whatever it holds
            out.skin = SkinBinding("none", skeleton.GetPrim())
            out.warnings.append(f"skinning none: the rest pose is refined and the binding to {skeleton.GetPath()} is "
                                "dropped; the refined mesh does not deform")
            return out
        out.skin = self._binding(out, skeleton, self.cache_of(prim))
        out.skin.refused = refused
        if out.baked:
            _bake_point_arrays(out)
        return out

    def _binding(self, sp: SkinnedPrim, skeleton, cache) -> SkinBinding:
        """The checked binding of ``sp`` to ``skeleton``; its times of change when baking."""
        prim, path = sp.prim, sp.path
        skel_query = cache.GetSkelQuery(skeleton)
        if not skel_query:
            raise SubdivInputError(f"{skeleton.GetPath()}: not a valid Skeleton (joints / bindTransforms / "
                                   f"restTransforms do not fit), bound by {path}")
        skel_joints = list(skel_query.GetJointOrder())
        anim_query = skel_query.GetAnimQuery()
        # the animation UsdSkel poses the skeleton with; where it finds none, why (a target that is not one)
        animation = anim_query.GetPrim() if anim_query else _animation_of(skeleton.GetPrim(), path)
        if animation is None and not skeleton.GetRestTransformsAttr().HasAuthoredValue():
            raise SubdivInputError(f"{skeleton.GetPath()}: no skel:animationSource and no restTransforms: UsdSkel "
                                   f"has no pose for the skeleton that {path} is bound to")
        query = cache.GetSkinningQuery(prim)
        binding = SkinBinding(self.mode, skeleton.GetPrim(), skel_query=skel_query, skinning_query=query,
                              animation=animation)
        n = len(sp.points_default)
        if _authored(prim, "primvars:skel:jointIndices") or _authored(prim, "primvars:skel:jointWeights"):
            binding.influences = _influences(prim, path, n, skel_joints)
            _check_weight_sums(sp, binding.influences)
        if _authored(prim, "skel:blendShapes"):
            binding.blend_query = _blend_shapes(prim, path, n, animation)
        if query is None or not query:
            raise SubdivInputError(f"{path}: bound to {skeleton.GetPath()} but UsdSkel finds no valid skinning "
                                   "(primvars:skel:jointIndices / jointWeights or skel:blendShapes)")
        binding.method = str(query.GetSkinningMethod() or "classicLinear")
        binding.all_times = _pose_times(prim, skeleton.GetPrim(), animation, binding)
        binding.times = times_for_frames(binding.all_times, self.frames)
        binding.time_codes_per_second = float(prim.GetStage().GetTimeCodesPerSecond())
        binding.max_influences = self.max_influences
        return binding


def _bake_point_arrays(sp: SkinnedPrim) -> None:
    """A baked pose's points are sampled at its times; authored velocities become the pose's, written at the
    same times (:func:`pose_velocities`); authored accelerations, the input's and not the pose's, are dropped
    (blocked, with a warning)."""
    sp.point_times = sp.skin.times
    if "velocities" in sp.point_arrays:
        sp.point_arrays["velocities"] = list(sp.skin.times)
        sp.stand_in_defaults.discard("velocities")
    if sp.point_arrays.pop("accelerations", None) is not None:
        sp.stand_in_defaults.discard("accelerations")
        sp.dropped.append(("accelerations", "authored accelerations of a skinned mesh are not those of its baked "
                                            "pose; its velocities are the pose's"))


def _authored(prim, name) -> bool:
    attr = prim.GetAttribute(name)
    return bool(attr) and attr.HasAuthoredValue()


def _animation_of(skeleton: Usd.Prim, path: str):
    """The SkelAnimation posing ``skeleton`` (its inherited skel:animationSource), None when none is bound;
    SubdivInputError when the relationship names something else."""
    api = UsdSkel.BindingAPI(skeleton)
    source = api.GetInheritedAnimationSource()
    if source and UsdSkel.IsSkelAnimationPrim(source):
        return source
    rel = api.GetAnimationSourceRel()
    targets = rel.GetTargets() if rel else []
    if targets:
        raise SubdivInputError(f"{skeleton.GetPath()}: skel:animationSource targets {targets[0]}, which is not a "
                               f"SkelAnimation (the skeleton {path} is bound to)")
    return None


def _primvar_rows(prim, name, path, points: int):
    """(values (rows, elementSize), interpolation) of joint-influence primvar ``name``, checked."""
    pv = UsdGeom.Primvar(prim.GetAttribute(name))
    values = pv.ComputeFlattened() if pv else None  # indexed or not, as UsdSkel reads them
    if values is None:
        raise SubdivInputError(f"{path}: {name} has no value (a skinned mesh needs jointIndices and jointWeights)")
    if pv.GetAttr().GetNumTimeSamples() > 0:
        raise SubdivInputError(f"{path}: {name} is time-sampled; UsdSkel reads joint influences once")
    interp = str(pv.GetInterpolation())
    es = pv.GetElementSize() or 1
    arr = np.asarray(values).reshape(-1)
    rows = 1 if interp == "constant" else points
    if interp not in ("constant", "vertex"):
        raise SubdivInputError(f"{path}: {name} has {interp} interpolation; joint influences are vertex or constant")
    if len(arr) != rows * es:
        raise SubdivInputError(f"{path}: {name} has {len(arr)} values; with elementSize {es} and {interp} "
                               f"interpolation it needs {rows * es} ({rows} x {es})")
    return arr.reshape(rows, es), interp


def _influences(prim, path, points: int, skel_joints: list) -> Influences:
    """The joint influences of ``prim``, checked against each other, its points and its joints."""
    idx, interp = _primvar_rows(prim, "primvars:skel:jointIndices", path, points)
    weights, w_interp = _primvar_rows(prim, "primvars:skel:jointWeights", path, points)
    if idx.shape[1] != weights.shape[1] or interp != w_interp:
        raise SubdivInputError(f"{path}: primvars:skel:jointIndices (elementSize {idx.shape[1]}, {interp}) and "
                               f"primvars:skel:jointWeights (elementSize {weights.shape[1]}, {w_interp}) differ")
    joints_attr = prim.GetAttribute("skel:joints")
    joints = list(joints_attr.Get()) if joints_attr and joints_attr.HasAuthoredValue() else skel_joints
    known = set(skel_joints)
    missing = [j for j in joints if j not in known]
    if missing:
        raise SubdivInputError(f"{path}: skel:joints names {missing[0]!r}, which is not a joint of the skeleton")
    bad = np.flatnonzero((idx.reshape(-1) < 0) | (idx.reshape(-1) >= len(joints)))
    if len(bad):
        raise SubdivInputError(f"{path}: primvars:skel:jointIndices[{bad[0]}] = {idx.reshape(-1)[bad[0]]} is not one "
                               f"of the {len(joints)} joints", element="vertex", index=int(bad[0]),
                               value=int(idx.reshape(-1)[bad[0]]))
    bad = np.flatnonzero(~np.isfinite(weights.reshape(-1)) | (weights.reshape(-1) < 0))
    if len(bad):
        raise SubdivInputError(f"{path}: primvars:skel:jointWeights[{bad[0]}] = {weights.reshape(-1)[bad[0]]:g} is "
                               "not a finite weight >= 0", element="vertex", index=int(bad[0]))
    return Influences(idx.astype(np.int64), weights.astype(np.float64), interp, joints)


def _check_weight_sums(sp, influences: Influences) -> None:
    """Warn where weights do not sum to one: UsdSkel skins with them as they are (the bake draws what it draws)."""
    sums = influences.weights.sum(axis=1)
    off = np.abs(sums - 1.0)
    if off.max() > WEIGHT_SUM_TOLERANCE:
        worst = int(np.argmax(off))
        count = int(np.count_nonzero(off > WEIGHT_SUM_TOLERANCE))
        sp.warnings.append(f"primvars:skel:jointWeights do not sum to one at {count} of {len(sums)} points (point "
                           f"{worst}: {sums[worst]:g}); UsdSkel skins with them as they are, and so does the bake "
                           "(skinning keep normalises them)")


def _blend_shapes(prim, path, points: int, animation):
    """The UsdSkel.BlendShapeQuery of ``prim``, its targets checked (each a BlendShape whose offsets fit its
    point indices and the mesh's points)."""
    api = UsdSkel.BindingAPI(prim)
    names = list(api.GetBlendShapesAttr().Get() or [])
    targets = api.GetBlendShapeTargetsRel().GetTargets()
    if len(names) != len(targets):
        raise SubdivInputError(f"{path}: skel:blendShapes names {len(names)} shapes, skel:blendShapeTargets "
                               f"{len(targets)}")
    for name, target in zip(names, targets):
        shape = UsdSkel.BlendShape(prim.GetStage().GetPrimAtPath(target))
        if not shape:
            raise SubdivInputError(f"{path}: skel:blendShapeTargets names {target}, which is not a BlendShape")
        offsets = shape.GetOffsetsAttr().Get()
        ids = shape.GetPointIndicesAttr().Get()
        n = len(offsets or [])
        if ids is not None and len(ids):
            ids = np.asarray(ids)
            if len(ids) != n:
                raise SubdivInputError(f"{target}: offsets has {n} entries for {len(ids)} pointIndices (blend shape "
                                       f"{name!r} of {path})")
            bad = np.flatnonzero((ids < 0) | (ids >= points))
            if len(bad):
                raise SubdivInputError(f"{target}: pointIndices[{bad[0]}] = {ids[bad[0]]} is not a point of {path} "
                                       f"(it has {points})")
        elif n != points:
            raise SubdivInputError(f"{target}: offsets has {n} entries without pointIndices; {path} has {points} "
                                   "points")
    return UsdSkel.BlendShapeQuery(api)


def _xform_times(prim: Usd.Prim, stop: Sdf.Path) -> set:
    """Time samples of the transforms of ``prim`` and its ancestors below ``stop`` (their common ancestor with
    the other prim: above it, transforms cancel)."""
    out: set = set()
    while prim and prim.GetPath() != stop and not prim.IsPseudoRoot():
        if prim.IsA(UsdGeom.Xformable):
            out.update(UsdGeom.Xformable(prim).GetTimeSamples())
        prim = prim.GetParent()
    return out


def _pose_times(prim, skeleton, animation, binding: SkinBinding) -> list:
    """Every time the deformed points of ``prim`` may change at: the animation's joint transforms and blend-shape
    weights, the mesh's points and influences, the transforms between skeleton and mesh."""
    times = set(prim.GetAttribute("points").GetTimeSamples())
    if animation is not None:
        anim = binding.skel_query.GetAnimQuery()
        times.update(anim.GetJointTransformTimeSamples())
        times.update(anim.GetBlendShapeWeightTimeSamples())
    common = prim.GetPath().GetCommonPrefix(skeleton.GetPath())
    times |= _xform_times(prim, common) | _xform_times(skeleton, common)
    for name in ("primvars:skel:geomBindTransform", "skel:skinningMethod"):
        attr = prim.GetAttribute(name)
        if attr:
            times.update(attr.GetTimeSamples())
    return sorted(float(t) for t in times)


def _check_animation(binding: SkinBinding, time) -> None:
    """UsdSkel poses a skeleton whose animation arrays do not fit its joints as its rest pose, with only a
    warning on the console: refuse instead, naming the animation and attribute."""
    anim = binding.animation
    if anim is None:
        return
    joints = UsdSkel.Animation(anim).GetJointsAttr().Get()
    shapes = UsdSkel.Animation(anim).GetBlendShapesAttr().Get()
    when = "" if time == DEFAULT else f" at time {time:g}"
    for name, expected in (("translations", joints), ("rotations", joints), ("scales", joints),
                           ("blendShapeWeights", shapes)):
        value = anim.GetAttribute(name).Get(time)
        if value is not None and len(value) != len(expected or []):
            what = "joints" if name != "blendShapeWeights" else "blendShapes"
            raise SubdivInputError(f"{anim.GetPath()}: {name}{when} has {len(value)} entries for {len(expected or [])} "
                                   f"{what}", element=name, value=len(value))


def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64).reshape(4, 4)


def skinned_points(sp: SkinnedPrim, time, space: str = "mesh") -> np.ndarray:
    """The control points of ``sp`` at ``time`` as UsdSkel deforms them (blend shapes, then joints), float64
    (n, 3), in the mesh's own space (``space="mesh"``) or the skeleton's (``"skeleton"``, where UsdSkel skins).
    UsdSkel skins in the skeleton's space; like :func:`pxr.UsdSkel.BakeSkinning`, the bake brings the points into
    the mesh's by the skeleton's local-to-world transform and the inverse of the mesh's, and rounded to float32
    (the points' type, and UsdSkel's), so that every request of a time gets the same values. The mesh's points are
    kept for a second request of the same time (refining ahead, then writing)."""
    skin = sp.skin
    if space != "mesh":
        return _skin(sp, blended_points(sp, time), time)
    key = "default" if time == DEFAULT else float(time)
    with skin.lock:
        held = skin.cache.pop(key, None)
        if held is not None:
            return held.astype(np.float64)
        kept = _to_mesh_space(sp, _skin(sp, blended_points(sp, time), time), time).astype(np.float32)
        held_bytes = sum(a.nbytes for a in skin.cache.values())
        while skin.cache and held_bytes + kept.nbytes > CACHE_BYTES:  # the oldest first (dicts keep their order)
            held_bytes -= skin.cache.pop(next(iter(skin.cache))).nbytes
        if kept.nbytes <= CACHE_BYTES:
            skin.cache[key] = kept
        return kept.astype(np.float64)


def blended_points(sp: SkinnedPrim, time):
    """The mesh's points at ``time`` with its blend shapes applied by UsdSkel (a Vt.Vec3fArray, the mesh's
    space)."""
    skin, prim = sp.skin, sp.prim
    points = prim.GetAttribute("points").Get(time)
    if points is None or len(points) != len(sp.points_default):
        points = Vt.Vec3fArray.FromNumpy(np.asarray(sp.points_default, dtype=np.float32))
    _check_animation(skin, time)
    if skin.blend_query is not None:
        anim = skin.skel_query.GetAnimQuery()
        weights = anim.ComputeBlendShapeWeights(time) if anim else None
        if weights is not None and len(weights):
            mapper = skin.skinning_query.GetBlendShapeMapper()
            if mapper is not None and not mapper.IsNull():
                weights = mapper.Remap(weights)
            query = skin.blend_query
            sub, shapes, subs = query.ComputeSubShapeWeights(weights)
            if not query.ComputeDeformedPoints(sub, shapes, subs, query.ComputeBlendShapePointIndices(),
                                               query.ComputeSubShapePointOffsets(), points):
                when = "" if time == DEFAULT else f" at time {time:g}"
                raise SubdivInputError(f"{sp.path}: UsdSkel could not apply the blend shapes{when}")
    return points


def _skin(sp: SkinnedPrim, points, time):
    """``points`` (a Vt.Vec3fArray) skinned by UsdSkel at ``time`` (the skeleton's space); unchanged (the mesh's
    space) for a mesh with blend shapes only."""
    skin = sp.skin
    if skin.influences is None:
        return np.asarray(points, dtype=np.float64)
    xforms = skin.skel_query.ComputeSkinningTransforms(time)
    if xforms is None or not skin.skinning_query.ComputeSkinnedPoints(xforms, points, time):
        when = "" if time == DEFAULT else f" at time {time:g}"
        raise SubdivInputError(f"{sp.path}: UsdSkel could not skin the points{when} (skeleton "
                               f"{skin.skeleton.GetPath()})")
    return np.asarray(points, dtype=np.float64)


def _to_mesh_space(sp: SkinnedPrim, pts: np.ndarray, time) -> np.ndarray:
    if sp.skin.influences is None:
        return pts  # blend shapes only: already in the mesh's space
    to_local = (_matrix(UsdGeom.Imageable(sp.skin.skeleton).ComputeLocalToWorldTransform(time))
                @ np.linalg.inv(_matrix(UsdGeom.Imageable(sp.prim).ComputeLocalToWorldTransform(time))))
    return pts @ to_local[:3, :3] + to_local[3, :3]


def pose_velocities(sp: SkinnedPrim, time) -> np.ndarray:
    """The velocities of the baked pose of ``sp`` at ``time`` (float64 (n, 3), the mesh's space, per second as
    USD's are): the difference of the deformed control points at the neighbouring times the pose changes at
    (every one, not only the selected: a range of frames baked alone writes what the whole bake writes), over
    the time between them, times the stage's timeCodesPerSecond. At a time the pose changes at, the central
    difference of the two around it (one-sided at the first and last); between two, the slope of the line USD
    interpolates there; zero at the default time (a pose at no time) and for a pose that never changes.
    Refinement is linear: the refined velocities are the refinement of these."""
    skin = sp.skin
    times = np.asarray(skin.all_times, dtype=np.float64)
    if time == DEFAULT or len(times) < 2:
        return np.zeros((len(sp.points_default), 3))
    t = float(time)
    below, above = np.searchsorted(times, t, side="left"), np.searchsorted(times, t, side="right")
    before = times[below - 1] if below > 0 else t
    after = times[above] if above < len(times) else t
    if after == before:
        return np.zeros((len(sp.points_default), 3))
    scale = skin.time_codes_per_second / (after - before)
    return (skinned_points(sp, after) - skinned_points(sp, before)) * scale


def posed_points(prim: Usd.Prim, time, skinning: Skinning | None = None):
    """The points of mesh ``prim`` at ``time`` as UsdSkel poses them (float64 (n, 3), in the mesh's space), or
    None when no skeleton deforms it: what ``render`` draws for a skinned mesh. ``skinning``: the
    :class:`Skinning` to reuse (its UsdSkel caches), else a new one."""
    if not is_bound(prim):
        return None
    sp = (skinning or Skinning(pose_instances=True)).attach(read_mesh(prim, scheme="catmull-clark", force=True))
    if sp is None or getattr(sp, "skin", None) is None or sp.skin.mode != "bake":
        return None
    return sp.points_at(time)


def _seen_from(prim: Usd.Prim, near: Usd.Prim) -> Sdf.Path:
    """The path of ``prim`` as seen through the instance that ``near`` (an instance proxy) is in: UsdSkel gives
    the prototype's prims inside instances (/__Prototype_1/...), the bake names the instance's."""
    path = prim.GetPath()
    if not prim.IsInPrototype() or not near.IsInstanceProxy():
        return path
    instance = near
    while instance and not instance.IsInstance():
        instance = instance.GetParent()
    prototype = instance.GetPrototype().GetPath() if instance else None
    return path.ReplacePrefix(prototype, instance.GetPath()) if prototype and path.HasPrefix(prototype) else path


def describe_skinning(sp) -> str | None:
    """One line on how mesh ``sp`` (as planned) is skinned, or None when no skeleton deforms it (``info``): what
    it is bound to, the times its pose changes at, and what the run's treatment does with it; where "bake" is
    refused (inside an instance), why, and the treatments that apply."""
    skin = getattr(sp, "skin", None)
    if skin is None or skin.skel_query is None:
        return None if skin is None or skin.skeleton is None else f"skinning none: bound to {skin.skeleton.GetPath()}"
    parts = [f"bound to {skin.skeleton.GetPath()} ({len(skin.skel_query.GetJointOrder())} joints"
             + (f", animation {_seen_from(skin.animation, skin.skeleton)}" if skin.animation is not None
                else ", rest pose") + ")"]
    if skin.influences is not None:
        inf = skin.influences
        parts.append(f"{inf.weights.shape[1]} {inf.interpolation} influences, {skin.method}")
    if skin.blend_query is not None:
        parts.append(f"{skin.blend_query.GetNumBlendShapes()} blend shapes")
    times = skin.times
    when = f"{len(times)} times ({times[0]:g} to {times[-1]:g})" if times else "the default time only"
    if skin.refused is not None:
        parts.append(f"posed at {when}; skinning {skin.refused}")
    elif skin.mode == "bake":
        parts.append("baked at " + when)
    else:
        parts.append(f"posed at {when}; skinning {skin.mode}: the rest pose refined")
    return "; ".join(parts)


__all__ = ["SKINNING_MODES", "INFLUENCE_PRIMVARS", "SkinBinding", "SkinnedPrim", "Skinning", "Influences",
           "check_skinning", "check_max_influences", "skinned_points", "blended_points", "CACHE_BYTES",
           "describe_skinning", "posed_points", "pose_velocities", "INSTANCE_REFUSAL"]
