"""Primvars of a refined mesh: vertex, varying, uniform and face-varying primvars rewritten for the refined
faces (constant ones are inherited as they are); those that cannot be refined are blocked, with a warning.

Vertex primvars are refined by the subdivision rules (limit values with ``limit``), varying ones and those of
bilinear meshes linearly inside each control face, uniform ones follow their control faces, face-varying ones
go through the refiner's face-varying channels (OpenSubdiv's FVarLinearInterpolation modes) where it has them,
else linearly per face.
"""
from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd

from ..errors import SubdivInputError
from ..io.usd_read import SubdivPrim
from ..io.usd_stage import DEFAULT
from ..io.usd_write import int_array, vt_array
from ..refiner import Refiner
from ..runtime import phases as _phases

T = Sdf.ValueTypeNames


def default_or_sample(t, value):
    """The value and time samples arguments of :meth:`~warp_subdiv.io.usd_write.OutputLayer.set` that author
    ``value`` at ``t``: the default value, or one time sample."""
    return (value, None) if t == DEFAULT else (None, [(t, value)])


def drop_attribute(sp, layer, prim, name, reason, warnings):
    """Block attribute ``name`` of ``sp`` (and its indices) on the output, with a warning saying why."""
    attr = sp.prim.GetAttribute(name)
    layer.block(prim, name, attr.GetTypeName(), custom=attr.IsCustom())
    if sp.prim.GetAttribute(name + ":indices").HasAuthoredValue() or name + ":indices" in prim.attributes:
        layer.block(prim, name + ":indices", T.IntArray)
    warnings.append(f"{sp.path}: {name} dropped ({reason})")


def write_primvars(sp, layer, prim, refinement, fvar_mode, warnings, limit, times_of, dropped: set) -> None:
    """Refine every primvar of ``sp`` not in ``dropped`` at its written times (``times_of(pv.times)``) with
    ``refinement`` (a :class:`~warp_subdiv.usd.refinement.MeshRefinement`). A primvar whose values do not fit is
    dropped (blocked, named in ``warnings``) and added to ``dropped``: a mesh whose topology changes over time
    writes its primvars once per topology, and a primvar dropped at one stays dropped."""
    for pv in sp.primvars:
        if pv.name in dropped:
            continue
        try:
            write_primvar(sp, pv, layer, prim, refinement, fvar_mode, warnings, limit, times_of(pv.times))
        except SubdivInputError as exc:
            dropped.add(pv.name)
            drop_attribute(sp, layer, prim, pv.name, str(exc).split(": ", 1)[-1], warnings)


def write_primvar(sp, pv, layer, prim, refinement, fvar_mode=None, warnings=None, limit=False, times=None):
    """Refine one primvar at ``times`` (default: the default time and each of its selected samples). A default
    that does not fit the mesh beside time samples gives way to the first selected sample (with a warning).
    ``limit``: vertex and face-varying values are limit values (as the points are with ``limit``). Where the
    input's indexing changes at a sample, the primvar is also written just before it (:func:`held_time`)."""
    previous = None
    for t in ([DEFAULT] + list(pv.times)) if times is None else times:
        if t != DEFAULT:
            held = held_time(pv, previous, t) if previous is not None else None
            if held is not None:
                write_primvar_at(sp, pv, held, layer, prim, refinement, fvar_mode, limit)
            previous = t
        try:
            write_primvar_at(sp, pv, t, layer, prim, refinement, fvar_mode, limit)
        except SubdivInputError as exc:
            if t != DEFAULT or not pv.times or pv.default_time is not None:
                raise
            write_primvar_at(sp, pv, t, layer, prim, refinement, fvar_mode, limit, read_at=pv.times[0])
            if warnings is not None:
                warnings.append(f"{sp.path}: {pv.name} default does not fit the mesh ({str(exc).split(': ', 1)[-1]})"
                                f": the sample at time {pv.times[0]:g} stands in for it")


def held_time(pv, previous: float, t: float):
    """The time just before sample ``t`` (the written time before it: ``previous``) at which primvar ``pv`` is
    written as the input reads it there, or None where none is needed.

    USD interpolates an indexed primvar's values between two samples but holds its indices (and holds values
    whose count changes): up to ``t`` the input reads the earlier indices with values interpolated towards
    those of ``t``. Refined samples are flattened (vertex and varying) or indexed anew (face-varying) per
    sample, and USD would interpolate from the earlier refined values to those of ``t``, which another indexing
    built. Where the indexing changes at ``t``, the refinement of the input as it reads a step before ``t``
    (``Usd.TimeCode.SafeStep``) ends the earlier stretch, so that the output reads as the input at every time
    but within that step. Indexed uniform primvars need none: their values are the input's, under indices
    that are remapped, and held, alike."""
    if not pv.indexed or pv.interpolation == "uniform":
        return None
    before = t - Usd.TimeCode.SafeStep(max(1e6, abs(t)))
    if before <= previous:
        return None
    (values, indices), (values_at, indices_at) = pv.raw(before), pv.raw(t)
    if values is None or values_at is None:
        return None
    if len(values) == len(values_at) and np.array_equal(np.asarray(indices), np.asarray(indices_at)):
        return None
    return before


@_phases.timed("refine")
def write_primvar_at(sp, pv, t, layer, prim, refinement, fvar_mode, limit=False, read_at=None):
    """Refine primvar ``pv`` as it is at ``read_at`` (default ``t``) and author it at ``t``."""
    mesh = sp.mesh
    refiner, fmap, linear_field = refinement.refiner, refinement.fmap, refinement.linear_field
    where = sp.path
    at = t if read_at is None else read_at
    n_expected = {"vertex": mesh.num_vertices, "varying": mesh.num_vertices, "uniform": mesh.num_faces,
                  "faceVarying": len(mesh.face_vertex_indices)}[pv.interpolation]
    spec = layer.attr(prim, pv.name, pv.type_name, custom=pv.primvar.GetAttr().IsCustom())
    raw, raw_idx = pv.raw(at)
    if raw is None:
        if t == DEFAULT:
            return
        raise SubdivInputError(f"{where}: {pv.name} has no value at time {t:g}")
    like = np.asarray(raw)
    if pv.interpolation == "uniform" and pv.indexed:
        _, idx = pv.elements(at, where)  # checked against the values' elements (elementSize values each)
        if idx is None or len(idx) != n_expected:  # indices count elements, one per face
            raise SubdivInputError(f"{where}: {pv.name}:indices has {0 if idx is None else len(idx)} entries "
                                   f"for {n_expected} faces")
        new_idx = idx[fmap.parent]
        idx_spec = layer.attr(prim, pv.name + ":indices", T.IntArray)
        layer.set(idx_spec, *default_or_sample(t, int_array(new_idx)))
        return
    if pv.interpolation == "faceVarying" and fvar_mode is not None:
        values, new_idx = refinement.face_varying(*face_varying_input(sp, pv, at), fvar_mode)
        values = np.asarray(values).reshape(len(values), -1)
        shaped = values.reshape((len(values) * pv.element_size,) + like.shape[1:])
        layer.set(spec, *default_or_sample(t, vt_array(pv.type_name, shaped, like)))
        idx_spec = layer.attr(prim, pv.name + ":indices", T.IntArray)
        layer.set(idx_spec, *default_or_sample(t, int_array(new_idx)))
        return
    rows = pv.flattened(at, where)
    if len(rows) != n_expected:
        raise SubdivInputError(f"{where}: {pv.name} has {len(rows)} {pv.interpolation} values, the mesh needs "
                               f"{n_expected}")
    if pv.interpolation == "uniform":
        out = rows[fmap.parent]
    elif pv.interpolation == "faceVarying":
        out = fmap.refine_corners(rows.astype(np.float64))
    elif pv.interpolation == "varying" or sp.scheme == "bilinear":
        out = linear_field(rows.astype(np.float64))
    else:  # vertex: the subdivision rules (with flatness), but prescribed normals move positions only
        out = refiner.evaluate(rows.astype(np.float64), normal_control=False)
        if limit:
            out = limit_values(refiner, out)
    shaped = np.asarray(out).reshape((len(out) * pv.element_size,) + like.shape[1:])
    layer.set(spec, *default_or_sample(t, vt_array(pv.type_name, shaped, like)))
    if pv.indexed and t == DEFAULT:
        layer.block(prim, pv.name + ":indices", T.IntArray)


def face_varying_input(sp: SubdivPrim, pv, t):
    """(values as float64 rows, value index per face corner) of face-varying primvar ``pv`` at ``t``, checked
    against the mesh's corners: what a refiner's face-varying channel takes. The writer and its workers
    (:meth:`~warp_subdiv.usd.refinement.MeshRefinement.run_ahead`) read it here alike, so a result computed
    ahead is found by these inputs."""
    rows, idx = pv.elements(t, sp.path)
    idx = np.arange(len(rows)) if idx is None else idx
    corners = len(sp.mesh.face_vertex_indices)
    if len(idx) != corners:
        raise SubdivInputError(f"{sp.path}: {pv.name} has {len(idx)} faceVarying values, the mesh needs {corners}")
    return rows.astype(np.float64), idx


def limit_values(refiner: Refiner, refined: np.ndarray) -> np.ndarray:
    """Limit values of refined vertex data (N, d) that is not a position: as the points' limit, but without
    normal control (which the refiner would apply to 3-wide data where its limit masks read one level deeper)."""
    data = np.asarray(refined, dtype=np.float64)
    return refiner.limit_points(data.reshape(len(data), -1), normal_control=False)
