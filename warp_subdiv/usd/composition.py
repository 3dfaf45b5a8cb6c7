"""The check that a bake's output composes to the refined data (:class:`CompositionCheck`), and the repairs that
make it do so where an opinion of the input is stronger than the place the refined data was written.

The refined data of a mesh is written once, at its unit's home in the output layer (its own path, a shared
mesh ``<container>/Mesh_<n>``, a refined prototype's content or a variant;
:class:`~warp_subdiv.usd.output_layout.Layout`), and reaches the composed mesh through the layer itself, an
internal reference or a variant. Some opinions of the input are stronger than such an arc: a local opinion on
a mesh that references a shared mesh, a class that instances inherit, a variant authored on an instance prim,
a local opinion beside a variant that holds the refined data. Each would show its control-mesh value beside
refined data: 6 colours on 24 faces, control texture coordinates with refined indices.

Every attribute the layer holds at a unit's home (points, topology, extent, normals, velocities, primvars and
their indices, subset indices, the blocked subdivision attributes) is therefore composed on every mesh it
was written for, and the strongest opinion of each must hold that unit's refined value. Where it does not:

* a mesh that references a shared refined mesh gets its own copy at its path (a local opinion of the output
  layer, the strongest there is);
* elsewhere the winning opinion, where it lies in the stage's layer stack (the input's root layer and its
  sublayers), is overridden at its own site in the output layer (the strongest layer of that stack) with the
  refined value: the composed mesh then takes what it took before, refined. Meshes whose refined values differ
  cannot share one such site, and a site that also reaches a mesh that is not refined cannot take a refined
  value: both are errors that name the opinion, as is an opinion outside the layer stack.

The output is then composed again and checked.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pxr import Pcp, Sdf, UsdGeom

from ..errors import SubdivInputError
from ..io.usd_write import OutputLayer


@dataclass
class CheckedMesh:
    """A composed mesh that must show a unit's refined data: its path, the variant configuration it composes
    in, the unit (``key``), and the path that references a shared refined mesh for it (None: not shared).
    ``local``: the output layer holds the refined data at the composed path itself, outside variants: the
    strongest opinion there is (the root layer's, at the prim's own site) for every attribute, so only its face
    count is checked."""

    composed: str
    config: object
    key: str
    shared: Sdf.Path | None = None
    local: bool = False

    def where(self) -> str:
        """The variant selections it composes with (those on it or its ancestors), for messages."""
        return "".join(f" with {vset} = {v} on {path}" for path, vset, v in self.config.selections
                       if Sdf.Path(self.composed).HasPrefix(Sdf.Path(path)))


@dataclass
class Instances:
    """A refined prototype's meshes as read through the top-level instance ``read``, and the top-level
    instances (``instances``, ``read`` first) through which they are checked: one of each USD prototype that
    references it (instances of one USD prototype compose alike)."""

    read_meshes: list
    read: str
    instances: list

    def meshes(self) -> list:
        """The :class:`CheckedMesh` of each mesh through each instance. A mesh read with variant selections
        made on or under ``read`` is checked through each instance with the same selections made on or under
        it, all of them in one configuration (selections on different instances do not interact)."""
        old = Sdf.Path(self.read)
        combined = {}
        for o in self.read_meshes:
            if o.config not in combined:
                moved = [_moved(o.config, old, Sdf.Path(path)) for path in self.instances]
                combined[o.config] = dataclasses.replace(
                    o.config, selections=tuple(dict.fromkeys(s for c in moved for s in c.selections)),
                    deinstanced=tuple(sorted({p for c in moved for p in c.deinstanced})))
        return [CheckedMesh(str(Sdf.Path(o.composed).ReplacePrefix(old, Sdf.Path(path))), combined[o.config], o.key)
                for path in self.instances for o in self.read_meshes]


def _moved(config, old: Sdf.Path, new: Sdf.Path):
    """A variant configuration (:func:`warp_subdiv.io.usd_scene.read_scene`'s) with its selections and
    de-instanced prims at or under ``old`` (an instance prim) moved under ``new`` (another one)."""
    if old == new or not config.selections and not config.deinstanced:
        return config

    def move(path):
        return str(Sdf.Path(path).ReplacePrefix(old, new))

    return dataclasses.replace(config, selections=tuple((move(p), s, v) for p, s, v in config.selections),
                               deinstanced=tuple(sorted(move(p) for p in config.deinstanced)))


@dataclass
class Loss:
    """A refined attribute of a checked mesh whose composed value comes from a stronger opinion: the attribute's
    path relative to the mesh (``.points``, ``subset.indices``), its path on the composed mesh, its path at the
    unit's home in the output layer, the winning spec (None: the attribute does not compose)."""

    mesh: CheckedMesh
    rel: Sdf.Path
    composed: Sdf.Path
    home: Sdf.Path
    winner: Sdf.PropertySpec | None


class CompositionCheck:
    """Composes the output of a bake and checks (and repairs, see the module) that every checked mesh shows its
    unit's refined data. ``homes``: unit -> home path; ``owners``: every output prim path that holds a unit's
    refined data (homes and copies) -> unit; ``faces``: unit -> refined face count. ``samples_only``: the layer
    holds time samples only (see :func:`~warp_subdiv.usd.refine_usd`): only the scheme is checked."""

    def __init__(self, layer: OutputLayer, homes: dict, owners: dict, faces: dict, samples_only: bool = False):
        self.layer, self.homes, self.owners, self.faces = layer, homes, owners, faces
        self.samples_only = samples_only
        self.patches: dict = {}  # attribute spec written over a stronger opinion -> units whose value it holds
        self.patched: dict = {}  # that spec's path -> the attribute's path relative to the mesh
        self._attributes: dict = {}

    def run(self, meshes: list, unshare, instanced=()) -> None:
        """Check every mesh of ``meshes`` (:class:`CheckedMesh`) and those of the refined prototypes
        ``instanced`` (:class:`Instances`); ``unshare(mesh)`` gives a shared mesh its own copy (and registers it
        in :attr:`owners`). Repairs, then checks again; SubdivInputError where the output cannot be repaired."""
        by_config: dict = {}
        for o in meshes + [o for group in instanced for o in group.meshes()]:
            by_config.setdefault(o.config, []).append(o)
        requests: dict = {}
        unshared = []
        for stage, items in self._stages(by_config):
            for o in items:
                losses = self.losses(stage, o)
                if losses and o.shared is not None:
                    unshared.append(o)
                    continue
                for loss in losses:
                    target = self._site_of(stage, loss)
                    requests.setdefault(target, []).append(loss)
        if not unshared and not requests:
            return
        for o in unshared:
            unshare(o)
        for target, losses in requests.items():
            self._patch(target, losses)
        for stage, items in self._stages(by_config):
            for o in items:
                for loss in self.losses(stage, o):
                    raise SubdivInputError(self._why(loss))
            self._check_reach(stage)

    def _stages(self, by_config: dict):
        """(the output composed in each configuration, its checked meshes), one stage at a time."""
        for config, items in by_config.items():
            stage = config.open(self.layer.layer)
            yield stage, items
            del stage

    # -- finding what loses -----------------------------------------------------------------------------
    def refined_attributes(self, key) -> list:
        """The attributes that hold a value at unit ``key``'s home, on the mesh and its subsets (the scheme
        only with ``samples_only``): (prim path relative to the mesh, [(attribute path relative to the mesh,
        home path), ...]) for the mesh and each subset."""
        if key not in self._attributes:
            layer, home = self.layer.layer, self.homes[key]
            out = []

            def walk(spec):
                attrs = []
                for attr in spec.attributes:
                    rel = attr.path.MakeRelativePath(home)
                    if self.samples_only and rel != Sdf.Path(".subdivisionScheme"):
                        continue
                    if attr.HasDefaultValue() or layer.GetNumTimeSamplesForPath(attr.path):
                        attrs.append((rel, attr.path))
                if attrs:
                    out.append((spec.path.MakeRelativePath(home), attrs))
                for child in spec.nameChildren:
                    walk(child)

            spec = layer.GetPrimAtPath(home)
            if spec is not None:
                walk(spec)
            self._attributes[key] = out
        return self._attributes[key]

    def losses(self, stage, o: CheckedMesh) -> list:
        """The refined attributes of checked mesh ``o`` whose composed value is not its unit's refined value."""
        prim = stage.GetPrimAtPath(o.composed)
        if not prim:
            return [Loss(o, Sdf.Path("."), Sdf.Path(o.composed), Sdf.Path(self.homes[o.key]), None)]
        out = []
        for rel_prim, attrs in () if o.local else self.refined_attributes(o.key):
            at = stage.GetPrimAtPath(rel_prim.MakeAbsolutePath(prim.GetPath()))
            stack = at.GetPrimStack() if at else []
            stronger = self._stronger_opinions(stack, o.key)
            for rel, home in attrs:
                if stronger is None:  # the unit's own spec does not compose here: the strongest opinion decides
                    winner = strongest_opinion(stack, rel.name)
                else:  # an opinion stronger than the unit's own spec, if any
                    winner = stronger.get(rel.name)
                    if winner is None:
                        continue
                if winner is None or not self._holds(winner, o.key):
                    out.append(Loss(o, rel, rel.MakeAbsolutePath(prim.GetPath()), home, winner))
        if not out and not self.samples_only:
            counts = prim.GetAttribute("faceVertexCounts").Get()
            if counts is None or len(counts) != self.faces[o.key]:
                raise SubdivInputError(
                    f"{o.composed}{o.where()}: composes to a faceVertexCounts of "
                    f"{0 if counts is None else len(counts)} faces, not the {self.faces[o.key]} refined")
        return out

    def _stronger_opinions(self, prim_stack, key):
        """{attribute name: strongest spec} of the values held by the specs of ``prim_stack`` that are stronger
        than the output layer's spec holding unit ``key``'s refined data (a home or a copy); None when no spec
        of the stack holds it."""
        found: dict = {}
        for prim_spec in prim_stack:
            if prim_spec.layer == self.layer.layer and self._owner(prim_spec.path) == key:
                return found
            layer = prim_spec.layer
            for attr in prim_spec.attributes:
                if attr.name not in found and (attr.HasDefaultValue() or layer.GetNumTimeSamplesForPath(attr.path)):
                    found[attr.name] = attr
        return None

    def _holds(self, spec, key) -> bool:
        """Whether ``spec`` (the strongest opinion of a refined attribute) holds unit ``key``'s refined value: a
        spec of the output layer at a place that holds that unit's data, or written over a stronger opinion
        with it."""
        if spec.layer != self.layer.layer:
            return False
        if spec.path in self.patches:
            return key in self.patches[spec.path]
        return self._owner(spec.path) == key

    def _owner(self, path: Sdf.Path):
        """The unit whose refined data the output layer holds at ``path`` (a mesh, or a subset or attribute of
        it), or None."""
        prim = path.GetPrimPath()
        while not prim.isEmpty and prim != Sdf.Path.absoluteRootPath:
            if prim in self.owners:
                return self.owners[prim]
            prim = prim.GetParentPath()
        return None

    # -- repairing ------------------------------------------------------------------------------------------
    def _site_of(self, stage, loss: Loss) -> Sdf.Path:
        """The path in the output layer where the refined value overrides the opinion that wins: the winner's
        own site, where it lies in the stage's layer stack; SubdivInputError otherwise."""
        winner = loss.winner
        stack = {layer.identifier for layer in stage.GetLayerStack(includeSessionLayers=False)}
        if winner is None or winner.layer == self.layer.layer or winner.layer.identifier not in stack:
            raise SubdivInputError(self._why(loss))
        return winner.path

    def _patch(self, target: Sdf.Path, losses: list) -> None:
        """Write the refined value of the losses' attribute over the opinion at ``target``; the units whose
        refined value is the same share it, any other is an error."""
        first = losses[0]
        self.layer.copy(first.home, target)
        self.patches[target] = {first.mesh.key}
        self.patched[target] = first.rel
        for loss in losses[1:]:
            if loss.mesh.key in self.patches[target]:
                continue
            if not same_values(self.layer.layer, first.home, loss.home):
                a, b = first.mesh, loss.mesh
                advice = ("refine without all_variants, or move the opinion into the variants (or the mesh into a "
                          "referenced asset)" if a.composed == b.composed else
                          "give each mesh its own opinion instead of one they share (a class or a referenced prim)")
                raise SubdivInputError(
                    f"{a.composed}{a.where()} and {b.composed}{b.where()}: {first.winner.layer.identifier} "
                    f"{target} is stronger than their refined {target.name}, which differ: the refined values cannot "
                    f"both be written there; {advice}")
            self.patches[target].add(loss.mesh.key)

    def _check_reach(self, stage) -> None:
        """Every mesh that takes a value written over a stronger opinion (a class, an internal reference,
        another prim's opinion may reach meshes that were not refined) must be refined, with that value."""
        cache = stage._GetPcpCache()
        for target, keys in self.patches.items():
            site = target.GetPrimPath()
            deps = cache.FindSiteDependencies(cache.layerStack, site, Pcp.DependencyTypeAnyIncludingVirtual,
                                              False, False, False)
            for dep in deps:
                prim = stage.GetPrimAtPath(dep.indexPath)
                # the site itself (a class, an over) and abstract prims that are not meshes are not drawn
                if not prim or dep.indexPath == site.StripAllVariantSelections() or (
                        prim.IsAbstract() and not prim.IsA(UsdGeom.Mesh)):
                    continue
                winner = strongest_opinion(prim.GetPrimStack(), target.name)
                if winner is None or winner.layer != self.layer.layer or winner.path != target:
                    continue
                key = self._unit_of(prim)
                if key is None or (key not in keys and not same_values(
                        self.layer.layer, target, self.patched[target].MakeAbsolutePath(self.homes[key]))):
                    what = "is not refined" if key is None else "refines to another value"
                    raise SubdivInputError(
                        f"{prim.GetPath()}: takes {target.name} from {target}, an opinion of the input that is "
                        f"stronger than the refined data of other meshes that take it too, but {what}: the refined "
                        "value cannot be written there; refine every mesh that takes it, or give the refined meshes "
                        "an opinion of their own")

    def _unit_of(self, prim):
        """The unit whose refined data ``prim`` composes (a spec of its prim stack that holds it), or None."""
        for spec in prim.GetPrimStack():
            if spec.layer == self.layer.layer:
                key = self._owner(spec.path)
                if key is not None:
                    return key
        return None

    def _why(self, loss: Loss) -> str:
        """Why the refined value of ``loss`` does not compose, for an error."""
        o, winner = loss.mesh, loss.winner
        what = str(loss.rel).lstrip(".") or "mesh"
        head = f"{o.composed}{o.where()}: the refined {what} written for it does not compose"
        if winner is None:
            return f"{head}: nothing composes at {loss.composed}"
        if winner.layer == self.layer.layer:
            return f"{head}: {winner.path} in the output is stronger and holds the refined value of another mesh"
        return (f"{head}: {winner.layer.identifier} {winner.path} is stronger and lies outside the stage's layer "
                "stack (the input file and its sublayers), where the output cannot override it")


def strongest_opinion(prim_stack, name: str):
    """The strongest spec of attribute ``name`` that holds a value (a default, a block or time samples), or None,
    in a composed prim's ``prim_stack`` (``Usd.Prim.GetPrimStack()``: its specs, strongest first, the order in
    which USD resolves its attributes' values; several times faster than each attribute's property stack)."""
    for prim_spec in prim_stack:
        layer = prim_spec.layer
        spec = layer.GetAttributeAtPath(prim_spec.path.AppendProperty(name))
        if spec is not None and (spec.HasDefaultValue() or layer.GetNumTimeSamplesForPath(spec.path)):
            return spec
    return None


def same_values(layer: Sdf.Layer, a: Sdf.Path, b: Sdf.Path) -> bool:
    """Whether the attribute specs at ``a`` and ``b`` of ``layer`` hold the same default and time samples."""
    sa, sb = layer.GetAttributeAtPath(a), layer.GetAttributeAtPath(b)
    if sa is None or sb is None:
        return sa is sb
    if sa.HasDefaultValue() != sb.HasDefaultValue() or (sa.HasDefaultValue() and not sa.default == sb.default):
        return False
    times = layer.ListTimeSamplesForPath(a)
    if list(times) != list(layer.ListTimeSamplesForPath(b)):
        return False
    return all(layer.QueryTimeSample(a, t) == layer.QueryTimeSample(b, t) for t in times)


__all__ = ["CheckedMesh", "CompositionCheck", "Instances", "Loss", "same_values", "strongest_opinion"]
