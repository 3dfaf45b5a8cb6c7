"""Where a bake writes the refined data in its output layer (:class:`Layout`, :func:`layout`): each distinct
input's home, the copies of it, the internal references of instances and shared meshes; and the check that
the composed output shows the refined data.

Meshes inside scene-graph instances go into a refined prototype (``/__warpSubdiv/Prototype_<n>``, under a
class) that every instance of the prototype references; identical meshes elsewhere are refined once and
written once (``/__warpSubdiv/Mesh_<n>``, referenced); with ``all_variants`` every variant that changes a mesh
is refined into the same variant set and variant (:func:`warp_subdiv.io.usd_read.read_scene`).
"""
from __future__ import annotations

from dataclasses import dataclass

from pxr import Sdf

from ..errors import SubdivInputError
from ..io.usd_stage import DEFAULT
from ..io.usd_write import OutputLayer
from ..runtime import phases as _phases
from .planning import Plan


#: The root prim of the output layer that holds refined prototypes and shared meshes (a class: not part of the
#: scene; a suffix is added where the input has a prim of that name).
CONTAINER = "__warpSubdiv"
#: The attributes whose composed values must come from the refined data (checked on the output).
_CHECKED = ("subdivisionScheme", "faceVertexCounts", "faceVertexIndices", "points")


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
        composes to its refined data: the strongest opinion of its topology, points and scheme must be the
        output layer's. A shared mesh that fails gets its own copy; anything else is an error naming the
        input's opinion that wins. ``samples_only``: the layer holds no default values (see :func:`refine_usd`),
        only the scheme, which it still holds, is checked."""
        scene = p.scene
        faces = {key: rep.faces_out for key, rep in zip(p.keys, reports)}
        todo = [(o.composed, o.config, o.key, o.dest if o.dest in self.shared else None) for o in scene.top.meshes]
        for key in self.prototypes:
            todo += [(o.composed, o.config, o.key, None) for o in scene.sites[key].meshes]
        by_config: dict = {}
        for item in todo:
            by_config.setdefault(item[1], []).append(item)
        for config, items in by_config.items():
            stage = config.open(layer.layer)
            for composed, _, key, shared in items:
                bad = _losing_opinion(stage.GetPrimAtPath(composed), layer.layer, faces[key], samples_only)
                if bad is None:
                    continue
                if shared is not None:  # the reference loses: write the mesh's own copy instead
                    layer.unreference(shared, self.homes[key])
                    layer.copy(self.homes[key], shared)
                    continue
                where = "".join(f" with {vset} = {v} on {path}" for path, vset, v in config.selections)
                raise SubdivInputError(
                    f"{composed}: the refined mesh written for it{where} does not compose: {bad} is stronger "
                    "(an opinion outside the variant or instance that carries the refined data); refine without "
                    "all_variants, or move the mesh into a referenced asset")
            del stage

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


def _losing_opinion(prim, layer: Sdf.Layer, faces: int, samples_only: bool = False):
    """None when the composed ``prim`` takes its refined attributes from ``layer`` (and has ``faces`` faces);
    else the stronger opinion (layer and spec path) that wins, as text. ``samples_only``: only the scheme is
    checked (a layer without default values: no topology, maybe no points)."""
    if not prim:
        return "nothing (the prim does not compose)"
    for name in _CHECKED[:1] if samples_only else _CHECKED:
        attr = prim.GetAttribute(name)
        stack = [s for s in attr.GetPropertyStack(DEFAULT)
                 if s.HasDefaultValue() or s.layer.GetNumTimeSamplesForPath(s.path)] if attr else []
        if stack and stack[0].layer != layer:
            return f"{stack[0].layer.identifier} {stack[0].path}"
    counts = prim.GetAttribute("faceVertexCounts").Get()
    if not samples_only and (counts is None or len(counts) != faces):
        return f"a faceVertexCounts of {0 if counts is None else len(counts)} faces (not {faces})"
    return None


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
