"""The kernels each record kind launches: :func:`apply` (dispatching on the record's type), :func:`displace`,
:func:`refine_step`, :func:`limit_positions`, :func:`limit_normals` and :func:`set_normals` launch the kernels of
:mod:`warp_subdiv.kernels` over a record and source and destination buffers (in the kernels' view,
:func:`~warp_subdiv.evaluator.buffers.kernel_view`), always on an explicit device, through a
:class:`~warp_subdiv.evaluator.launch.Launcher` (or a recorder of the launches).
"""
from __future__ import annotations

from functools import singledispatch

import warp as wp

from ..errors import SubdivInputError
from .launch import Launcher, _kernels, launcher
from .records import Displacement, ExplicitRows, LimitMasks, Projection, QuadStep, StencilStep, StepRecord, TriangleStep


@singledispatch
def apply(record, src: wp.array, dst: wp.array, device) -> None:
    """Write the rows of ``record`` into ``dst`` from ``src`` (both in one kernel view, see
    :func:`~warp_subdiv.evaluator.buffers.kernel_view`) on ``device`` (a Warp device, or a :class:`Launcher` that
    may split the launches over threads)."""
    raise TypeError(f"no evaluation for {type(record).__name__}")


@apply.register
def _(record: QuadStep, src, dst, device) -> None:
    k, run = _kernels(), launcher(device)
    V, F = record.num_vertices, record.num_faces
    # face points first: edge and vertex points read them from dst (the face points end before they start);
    # edge and vertex points read only src and face points and write their own rows: no barrier between them;
    # the explicit rows (the rows they skip) come after both, as they always did
    run.rows(k.quad_face_points, F, [record.corner_vert, src, dst, V, record.quarter])
    with run.together():
        if record.edge_ends is not None:  # expanded tables (the CPU's)
            run.rows(k.quad_edge_points_expanded, record.num_edges,
                     [record.edge_ends, record.edge_regular, src, dst, V, V + F, record.edge_weights])
            run.rows(k.quad_vertex_points_expanded, V,
                     [record.ring_offsets, record.ring_vertices, record.ring_faces, record.vertex_regular, src,
                      dst, V, record.ring_weights])
        else:
            run.rows(k.quad_edge_points, record.num_edges,
                     [record.edge_neighbours, record.corner_vert, record.edge_regular, src, dst, V, V + F,
                      record.edge_weights])
            run.rows(k.quad_vertex_points, V,
                     [record.ring_offsets, record.ring, record.corner_vert, record.vertex_regular, src, dst, V,
                      record.ring_weights])
    apply(record.explicit, src, dst, run)


@apply.register
def _(record: TriangleStep, src, dst, device) -> None:
    k, run = _kernels(), launcher(device)
    V = record.num_vertices
    with run.together():  # both read only src and write their own rows; the explicit rows come after both
        run.rows(k.tri_edge_points, record.num_edges,
                 [record.edge_neighbours, record.edge_regular, src, dst, V, record.edge_weights])
        run.rows(k.tri_vertex_points, V, [record.ring_offsets, record.ring, record.vertex_regular, src, dst,
                                          record.ring_weights])
    apply(record.explicit, src, dst, run)


@apply.register
def _(record: ExplicitRows, src, dst, device) -> None:
    launcher(device).rows(_kernels().explicit_rows, record.count,
                          [record.rows, record.offsets, record.indices, record.weights, src, dst])


@apply.register
def _(record: StencilStep, src, dst, device) -> None:
    launcher(device).rows(_kernels().stencil_rows, record.num_rows,
                          [record.offsets, record.indices, record.weights, src, dst])


@singledispatch
def displace(record, points: wp.array, scratch: wp.array, device) -> None:
    """Move the target rows of ``points`` in place; every row reads unmoved points (through ``scratch``)."""
    raise TypeError(f"no displacement for {type(record).__name__}")


@displace.register
def _(record: Displacement, points, scratch, device) -> None:
    k, run = _kernels(), launcher(device)
    tmp = scratch[: record.count]
    run.sliced(k.displace_rows, record.count, lambda a, b: [
        record.targets[a:b], record.offsets[a:b + 1], record.indices, record.weights, points, tmp[a:b]])
    _scatter(run, record.targets, tmp, points, record.count)


def _scatter(run: Launcher, targets, values, dst, n: int) -> None:
    """dst[targets[i]] = values[i] for i < n (after every row of ``values`` is computed)."""
    run.sliced(_kernels().scatter_rows, n, lambda a, b: [targets[a:b], values[a:b], dst])


@displace.register
def _(record: Projection, points, scratch, device) -> None:
    if points.ndim != 1:
        raise SubdivInputError("normal control applies to (n, 3) positions only", option="normal_control")
    k, run = _kernels(), launcher(device)
    tmp = scratch[: record.count]
    run.sliced(k.project_rows, record.count, lambda a, b: [
        record.targets[a:b], record.offsets[a:b + 1], record.indices, record.weights, record.normal_ids,
        record.normals, points, tmp[a:b]])
    _scatter(run, record.targets, tmp, points, record.count)


def refine_step(step: StepRecord, src: wp.array, dst: wp.array, scratch: wp.array | None, normal_control: bool,
                device) -> None:
    """One refinement step from ``src`` into ``dst`` (both in one kernel view, see
    :func:`~warp_subdiv.evaluator.buffers.kernel_view`): the child rows, then flatness, then (when
    ``normal_control``) normal control; ``scratch`` holds at least ``step.num_moved`` rows of the same view."""
    apply(step.rows, src, dst, device)
    if step.flatness is not None:
        displace(step.flatness, dst, scratch, device)
    if normal_control and step.normals is not None:
        displace(step.normals, dst, scratch, device)


def limit_positions(masks: LimitMasks, src: wp.array, out: wp.array, device) -> None:
    """Limit values of the masks' vertices from the level's points ``src`` (any width, ``out`` in the same
    view, ``masks.num_vertices`` rows; see :meth:`LimitMasks.first`)."""
    apply(masks.position, src, out, device)


def limit_normals(masks: LimitMasks, src: wp.array, tangent_u: wp.array, tangent_v: wp.array, out: wp.array,
                  device) -> None:
    """Unit limit normals ``out`` from positions ``src`` (vec3 arrays); ``tangent_u``/``tangent_v`` are vec3
    work buffers of ``masks.num_tangents`` rows."""
    run = launcher(device)
    apply(masks.tangent_u, src, tangent_u, run)
    apply(masks.tangent_v, src, tangent_v, run)
    zero = src.dtype()
    run.sliced(_kernels().vertex_normals, masks.num_vertices, lambda a, b: [
        masks.vertex_offsets[a:b + 1], tangent_u, tangent_v, zero, out[a:b]])


def set_normals(ids: wp.array, normals: wp.array, out: wp.array, device) -> None:
    """out[ids[i]] = normals[i]: prescribed normals replace the computed ones (vec3 arrays)."""
    launcher(device).sliced(_kernels().scatter_rows, ids.shape[0], lambda a, b: [ids[a:b], normals[a:b], out])


def limits(masks: LimitMasks, src: wp.array, outputs: tuple, prescribed, points: bool, normals: bool,
           device) -> None:
    """Limit points (when ``points``) and unit limit normals (when ``normals``) of the masks' vertices from the
    level's points ``src`` into ``outputs`` (points, tangent u, tangent v, normals); ``prescribed``: (ids,
    normals) device arrays of normals that replace the computed ones, or None."""
    out, tangent_u, tangent_v, normals_out = outputs
    if points:
        limit_positions(masks, src, out, device)
    if normals:
        limit_normals(masks, src, tangent_u, tangent_v, normals_out, device)
        if prescribed is not None:
            set_normals(*prescribed, normals_out, device)
