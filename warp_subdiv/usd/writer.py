"""One refined mesh written into a bake's output layer (:class:`PrimWriter`): an ``over`` with the refined
topology, points, extent, normals, velocities and accelerations, primvars and subsets, and the subdivision
attributes blocked.
"""
from __future__ import annotations

from pxr import Sdf

from ..io.usd_read import SUBDIVISION_ATTRIBUTES
from ..io.usd_stage import DEFAULT
from ..io.usd_write import extent_of, int_array, vec3f_array
from .planning import PrimReport
from .primvars import default_or_sample, drop_attribute, write_primvars
from .skinning_output import KEPT_NORMALS, stays_skinned, write_skinning
from .subsets import write_subsets

T = Sdf.ValueTypeNames


class PrimWriter:
    """Refines prim ``i`` of a :class:`~warp_subdiv.usd.refine.Bake` and writes it at ``target``, its path in the
    output layer (its own path, a prototype's content or a shared mesh; :class:`~warp_subdiv.usd.output_layout.Layout`).

    A mesh whose topology changes over time gets one refiner per distinct control mesh (built once, used for
    every time that has it), and time-sampled topology: each written time takes the refiner of its control
    mesh. With ``samples_only`` no default values are written (see :func:`~warp_subdiv.usd.refine_usd`)."""

    def __init__(self, bake, i: int, target: str, label: str):
        self.bake, self.i, self.target, self.label = bake, i, target, label
        self.sp = bake.plan.prims[i]
        self.layer = bake.layer
        self.prim = self.layer.prim(target)
        self.varying = bool(self.sp.topologies)
        self.dropped: set = set()  # primvars and subsets dropped: they stay dropped for the other topologies

    def write(self, prepared=None) -> PrimReport:
        """Write the mesh; ``prepared``: its refinement, built (and partly evaluated) ahead by a worker
        (:class:`~warp_subdiv.usd.ahead.Ahead`), or None."""
        sp, bake = self.sp, self.bake
        groups = range(len(sp.topologies)) if self.varying else [0]
        w_tables, w_sample = bake.progress.weights[self.i]
        normals_spec = self._block_control_attributes()
        fvar_mode = sp.face_varying_mode if sp.scheme != "bilinear" else None
        report = None
        for group in groups:
            spg = sp.with_topology(group)
            if prepared is not None and not self.varying:
                refinement, prepared = prepared, None
            else:
                refinement = bake.refinement(self.i, spg)
            bake.progress.step(w_tables / len(groups), f"{self.label}: {bake.plan.levels[self.i]} levels"
                               + (f" (topology {group + 1})" if self.varying else ""))
            self._write_topology(refinement, group)
            self._write_points(refinement, spg, group, normals_spec, w_sample)
            self._write_vectors(refinement, spg, group)

            def times_of(own, group=group):
                return self._written(self._times_of(own) if self.varying else [DEFAULT] + list(own), group)

            write_primvars(spg, self.layer, self.prim, refinement, fvar_mode, bake.warnings, bake.limit, times_of,
                           self.dropped)
            write_subsets(spg, self.target, self.layer, refinement, bake.warnings, times_of, self.dropped)
            write_skinning(spg, self.layer, self.prim, refinement, bake.warnings)  # a skeleton's binding
            if group == sp.default_topology or not self.varying:
                report = PrimReport(sp.path, sp.scheme, sp.rules if sp.scheme != "bilinear" else "-",
                                    spg.mesh.num_faces, len(refinement.counts), spg.mesh.num_vertices,
                                    refinement.refiner.num_vertices, len(sp.point_times) or 1,
                                    level=bake.plan.levels[self.i])
            del refinement
        return report

    def _block_control_attributes(self):
        """Block the subdivision attributes and every subdiv: tag, authored normals too (unless written), and the
        attributes the reader found cannot be refined; returns the spec of the normals written, or None."""
        sp, layer, prim, bake = self.sp, self.layer, self.prim, self.bake
        layer.set(layer.attr(prim, "subdivisionScheme", T.Token, uniform=True), "none")
        for name in SUBDIVISION_ATTRIBUTES:
            attr = sp.prim.GetAttribute(name)
            layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform)
        for name in sp.subdiv_attributes:
            attr = sp.prim.GetAttribute(name)
            layer.block(prim, name, attr.GetTypeName(), attr.GetVariability() == Sdf.VariabilityUniform, custom=True)
        normals_spec = None
        if bake.normals and sp.scheme != "bilinear" and not stays_skinned(sp):
            normals_spec = layer.attr(prim, "normals", T.Normal3fArray)
            normals_spec.SetInfo("interpolation", "vertex")
        elif bake.normals and sp.scheme != "bilinear":
            bake.warnings.append(f"{sp.path}: {KEPT_NORMALS}")
        elif bake.normals:
            bake.warnings.append(f"{sp.path}: a bilinear mesh has no limit normals; none written")
        for name in sp.authored_normals:
            if name == "normals" and normals_spec is not None:
                continue
            attr = sp.prim.GetAttribute(name)
            layer.block(prim, name, attr.GetTypeName())
            if name == "primvars:normals" and sp.prim.GetAttribute(name + ":indices"):
                layer.block(prim, name + ":indices", T.IntArray)
        for name, reason in sp.dropped:
            drop_attribute(sp, layer, prim, name, reason, bake.warnings)
        return normals_spec

    def _times_of(self, own) -> list:
        """[DEFAULT] and the written times of an attribute with time samples ``own``: with a time-varying
        topology, also every time where the topology changes (the refined value changes there)."""
        own = set(own) | (set(self.sp.topology_changes) if self.varying else set())
        return [DEFAULT] + sorted(own)

    def _written(self, times, group) -> list:
        """The written times of ``times`` that take the topology ``group`` (every list of written times passes
        here)."""
        if self.bake.samples_only:
            times = [t for t in times if t != DEFAULT]
        return [t for t in times if self.sp.topology_index(t) == group] if self.varying else list(times)

    def _write_topology(self, refinement, group) -> None:
        """The refined faces: the default, and with a time-varying topology a sample wherever it changes."""
        layer, prim = self.layer, self.prim
        cnt_spec = layer.attr(prim, "faceVertexCounts", T.IntArray)
        idx_spec = layer.attr(prim, "faceVertexIndices", T.IntArray)
        for t in self._written([DEFAULT] + list(self.sp.topology_changes if self.varying else []), group):
            layer.set(cnt_spec, *default_or_sample(t, int_array(refinement.counts)))
            layer.set(idx_spec, *default_or_sample(t, int_array(refinement.indices)))

    def _write_points(self, refinement, spg, group, normals_spec, w_sample) -> None:
        """Points, extent and normals: the default, then every selected time sample."""
        layer, prim, progress = self.layer, self.prim, self.bake.progress
        pts_spec = layer.attr(prim, "points", T.Point3fArray)
        ext_spec = layer.attr(prim, "extent", T.Float3Array)
        kept = self.bake.samples(self.i, group)  # time samples kept for a resumed bake, or None
        for t in self._written([DEFAULT] + list(self.sp.point_times), group):
            found = kept.get(t) if kept is not None and t != DEFAULT else None
            pos, nrm = found if found is not None else refinement.positions(spg.points_at(t))
            layer.set(pts_spec, *default_or_sample(t, vec3f_array(pos)))
            layer.set(ext_spec, *default_or_sample(t, extent_of(pos)))
            if normals_spec is not None:
                layer.set(normals_spec, *default_or_sample(t, vec3f_array(nrm)))
            if t != DEFAULT:
                if kept is not None and found is None:
                    kept.add(t, pos, nrm)
                progress.step(w_sample, f"{self.label}: time {t:g}", kept=found is not None)
        if kept is not None:
            kept.flush()
            if kept.reused:
                self.bake.reused_samples[self.sp.path] = self.bake.reused_samples.get(self.sp.path, 0) + kept.reused
        if not self.sp.point_times:
            progress.step(w_sample, f"{self.label}: points")

    def _write_vectors(self, refinement, spg, group) -> None:
        """Velocities and accelerations: derivatives of the points, refined by the same (linear) rules."""
        sp, layer, prim = self.sp, self.layer, self.prim
        for name, arr_times in sp.point_arrays.items():
            spec = layer.attr(prim, name, sp.prim.GetAttribute(name).GetTypeName())
            times = self._times_of(arr_times) if self.varying else [DEFAULT] + list(arr_times)
            for t in self._written(times, group):
                layer.set(spec, *default_or_sample(t, vec3f_array(refinement.vectors(spg.vector_array_at(name, t)))))
