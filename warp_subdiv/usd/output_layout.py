"""Where a bake writes the refined data in its output layer (:class:`Layout`, :func:`layout`): each distinct
input's home, the copies of it, the internal references of instances and shared meshes; and the check that
the composed output shows the refined data (made by :mod:`~warp_subdiv.usd.composition`, which also repairs
the output where an opinion of the input is stronger than the arc that brings the refined data).

Meshes inside scene-graph instances go into a refined prototype (``/__warpSubdiv/Prototype_<n>``, under a
class) that every instance of the prototype references; identical meshes elsewhere are refined once and
written once (``/__warpSubdiv/Mesh_<n>``, referenced); with ``all_variants`` every variant that changes a mesh
is refined into the same variant set and variant (:func:`warp_subdiv.io.usd_scene.read_scene`).
"""
from __future__ import annotations

from dataclasses import dataclass

from pxr import Sdf

from ..io.usd_write import OutputLayer
from ..runtime import phases as _phases
from .composition import CheckedMesh, CompositionCheck, Instances
from .planning import Plan


#: The root prim of the output layer that holds refined prototypes and shared meshes (a class: not part of the
#: scene; a suffix is added where the input has a prim of that name).
CONTAINER = "__warpSubdiv"


@dataclass
class Layout:
    """Where the refined data goes in the output layer.

    * ``homes``: the path each unit (a distinct input, :attr:`Plan.keys`) is written at; ``copies``: further
      paths that get a copy of it (inside variants, or in other prototypes' content);
    * ``refs``: internal references (path, target): each top-level instance prim references the refined
      content of its prototype (``<container>/Prototype_<n>``; nested instances reference theirs from inside
      it), and meshes outside instances with identical inputs reference one shared refined mesh
      (``<container>/Mesh_<n>``) written once;
    * ``shared``: those meshes' paths (a reference that the composed output shows to lose against a stronger
      opinion of the input becomes a copy).
    """

    container: Sdf.Path
    homes: dict
    copies: dict
    refs: list
    shared: dict
    prototypes: dict

    @_phases.timed("write")
    def write(self, layer: OutputLayer) -> None:
        """The container and the references (the refined data is written already)."""
        if self.prototypes or any(h.HasPrefix(self.container) for h in self.homes.values()):
            layer.container(self.container)
        for path, target in self.refs:
            layer.reference(path, target)

    @_phases.timed("write")
    def check(self, layer: OutputLayer, p: Plan, reports, *, samples_only: bool = False) -> None:
        """Compose the output (in each variant configuration that was read) and check that every refined mesh
        composes to its refined data: the strongest opinion of every attribute written at its unit's home must
        hold the refined value (:class:`~warp_subdiv.usd.composition.CompositionCheck`). A shared mesh where
        one does not gets its own copy; elsewhere the stronger opinion of the input is overridden with the
        refined value at its own site; what cannot be repaired is an error naming the opinion that wins.
        ``samples_only``: the layer holds no default values (see :func:`refine_usd`), only the scheme, which
        it still holds, is checked."""
        faces = {key: rep.faces_out for key, rep in zip(p.keys, reports)}
        todo = [CheckedMesh(o.composed, o.config, o.key, o.dest if o.dest in self.shared else None,
                            o.dest not in self.shared and o.dest == Sdf.Path(o.composed))
                for o in p.scene.top.meshes]
        instanced, groups = self._instanced_meshes(p.scene)
        owners = {home: key for key, home in self.homes.items()}
        for key, paths in self.copies.items():
            owners.update((path, key) for path in paths)
        shared = set(self.shared.values())
        CompositionCheck(layer, self.homes, owners, faces, samples_only).run(
            todo + instanced, lambda mesh: self._unshare(layer, mesh, owners), groups)
        self._drop_unreferenced(layer, shared)

    def _instanced_meshes(self, scene) -> tuple:
        """The meshes of refined prototypes to check: (meshes, :class:`~warp_subdiv.usd.composition.Instances`):
        the meshes of prototypes reached through nested instances only, as read; the others as read through one
        top-level instance, and through one other top-level instance of each other USD prototype that
        references the refined prototype in the same configuration (instances of one USD prototype compose
        alike, those of different ones may not: a class one of them inherits, a variant authored on it)."""
        meshes, groups = [], []
        for key in self.prototypes:
            site = scene.sites[key].meshes
            refs = [r for r in scene.top.refs if r.site == key]
            read = next((r for r in refs if site and Sdf.Path(site[0].composed).HasPrefix(Sdf.Path(r.composed))),
                        None)
            if read is None:  # reached through nested instances only: checked through the one it was read in
                meshes += [CheckedMesh(o.composed, o.config, o.key) for o in site]
                continue
            kept = {read.prototype: read.composed}
            for r in refs:
                if r.config == read.config:
                    kept.setdefault(r.prototype, r.composed)
            groups.append(Instances([CheckedMesh(o.composed, o.config, o.key) for o in site], read.composed,
                                    list(kept.values())))
        return meshes, groups

    def _unshare(self, layer: OutputLayer, mesh, owners: dict) -> None:
        """Give a mesh that references a shared refined mesh its own copy instead (a local opinion of the output
        layer, stronger than the input's opinions that the reference loses to)."""
        home = self.homes[mesh.key]
        layer.unreference(mesh.shared, home)
        layer.copy(home, mesh.shared)
        self.refs.remove((mesh.shared, home))
        del self.shared[mesh.shared]
        self.copies[mesh.key].append(mesh.shared)
        owners[mesh.shared] = mesh.key

    def _drop_unreferenced(self, layer: OutputLayer, keys) -> None:
        """Remove the shared refined meshes of units ``keys`` that every mesh got its own copy of (and the
        container, when nothing is left in it); a copy becomes the unit's home."""
        for key in keys:
            if key not in self.shared.values():
                layer.remove(self.homes[key])
                self.homes[key] = self.copies[key].pop(0)
        spec = layer.layer.GetPrimAtPath(self.container)
        if spec is not None and not spec.nameChildren:
            layer.remove(self.container)

    def hint_roots(self, p: Plan) -> dict:
        """Composed prims whose ancestors' extentsHint is recomputed, with the times written under them: the
        refined meshes outside instances and the instance prims that reference refined prototypes."""
        scene = p.scene
        times_of = {key: sp.point_times for key, sp in zip(p.keys, p.prims)}
        memo: dict = {}

        def site_times(key):
            if key not in memo:
                site = scene.sites[key]
                out = set()
                for o in site.meshes:
                    out.update(times_of[o.key])
                for r in site.refs:
                    out.update(site_times(r.site))
                memo[key] = out
            return memo[key]

        roots: dict = {}
        for o in scene.top.meshes:
            roots.setdefault(o.composed, set()).update(times_of[o.key])
        for r in scene.top.refs:
            roots.setdefault(r.composed, set()).update(site_times(r.site))
        return {path: sorted(times) for path, times in roots.items()}


def layout(p: Plan) -> Layout:
    """The output layout of a plan: prototypes named in the order the top level reaches them, each unit's home
    and copies, the references (see :class:`Layout`)."""
    name, n = CONTAINER, 1
    while p.stage.GetPrimAtPath("/" + name):
        n += 1
        name = f"{CONTAINER}_{n}"
    container = Sdf.Path("/" + name)
    targets, refs, prototypes = p.scene.layout(container)
    homes, copies, shared = {}, {}, {}
    count = 0
    for key in p.keys:
        paths = targets[key]
        plain = [t for t in paths if not t.ContainsPrimVariantSelection() and not t.HasPrefix(container)]
        if len(plain) >= 2:  # identical meshes outside instances: written once, referenced from each
            count += 1
            home = container.AppendChild(f"Mesh_{count}")
            for t in plain:
                refs.append((t, home))
                shared[t] = key
            copies[key] = [t for t in paths if t not in plain]
        else:
            home, copies[key] = paths[0], paths[1:]
        homes[key] = home
    return Layout(container, homes, copies, refs, shared, prototypes)
