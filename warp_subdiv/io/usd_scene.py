"""The scene of a USD stage: every subdivision mesh, inside instances, PointInstancer prototypes and (when asked)
every variant, read once per distinct input (:func:`input_fingerprint`), and where its refined data goes in the
output layer (:class:`Scene`, built by :func:`read_scene`).
"""
from __future__ import annotations

import dataclasses
import hashlib
import re
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdSkel

from .usd_stage import DEFAULT, check_roots

#: Where a prototype's refined content is collected before it gets its name in the output layer.
SITE = Sdf.Path("/__site__")
#: Attributes that never change what a mesh refines to (transforms, visibility, purpose).
_NOT_INPUTS = re.compile(r"^xformOp|^xformOpOrder$|^visibility$|^purpose$|^proxyPrim$")


def _hash_value(h, value) -> None:
    """Feed ``value`` to hash ``h``: a numeric array's shape and bytes (its buffer, not a copy), else its repr."""
    if value is None:
        h.update(b"\x00none")
        return
    try:
        arr = np.asarray(value)
        if arr.dtype.kind in "fiub":
            h.update(str(arr.shape).encode())
            h.update(np.ascontiguousarray(arr).reshape(-1).view(np.uint8))
            return
    except (TypeError, ValueError):
        pass
    h.update(repr(value).encode())


def skinned(prim: Usd.Prim) -> bool:
    """Whether a mesh takes part in UsdSkel: the binding API applied, or joint influences or blend shapes
    authored on it."""
    if prim.HasAPI(UsdSkel.BindingAPI):
        return True
    names = ("primvars:skel:jointIndices", "primvars:skel:jointWeights", "skel:blendShapes")
    return any(prim.GetAttribute(n).HasAuthoredValue() for n in names if prim.HasAttribute(n))


def input_fingerprint(prim: Usd.Prim) -> str:
    """A digest of everything a mesh refines from, as composed: the values (default and every time sample)
    and the interpolation / elementSize of every authored attribute of the mesh and of its children (face
    subsets), by name relative to the mesh, except transforms, visibility and purpose. Meshes with equal
    digests refine to the same data, wherever they sit and however they compose. A mesh bound to a UsdSkel
    skeleton is deformed by what binds it and by the transforms between it and the skeleton: its path goes into
    its digest, so that it is never taken for another."""
    h = hashlib.sha1()
    root = prim.GetPath()
    if skinned(prim):
        h.update(f"skinned {root}".encode())
    for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)):
        h.update(f"<{p.GetPath().MakeRelativePath(root)}:{p.GetTypeName()}>".encode())
        for attr in p.GetAttributes():
            name = attr.GetName()
            if _NOT_INPUTS.match(name) or not attr.HasValue():
                continue
            h.update(f"{name}:{attr.GetTypeName()}:{attr.GetMetadata('interpolation')}:"
                     f"{attr.GetMetadata('elementSize')}".encode())
            _hash_value(h, attr.Get(DEFAULT))
            for t in attr.GetTimeSamples():
                h.update(f"@{t!r}".encode())
                _hash_value(h, attr.Get(t))
    return h.hexdigest()


@dataclass
class Occurrence:
    """A place a refined mesh goes: its unit (input digest), its output path (absolute at the top level, under
    :data:`SITE` in a prototype's content), and the composed prim it was read from, with the variant
    selections of the configuration it was read in (for messages and checks)."""

    key: str
    dest: Sdf.Path
    composed: str
    config: object = None  # the _Config it was read in


@dataclass
class SiteRef:
    """An internal reference to a prototype's refined content (site ``site``), authored at ``dest``, for the
    instance prim ``composed`` (in configuration ``config``), whose USD prototype is ``prototype``: instances
    of one USD prototype compose alike."""

    dest: Sdf.Path
    site: str
    composed: str
    config: object = None
    prototype: str = ""


@dataclass
class Site:
    """The refined content of a subtree: the meshes it holds and the nested instances that reference other
    sites. The top level's paths are absolute; a prototype's are under :data:`SITE`."""

    meshes: list = field(default_factory=list)
    refs: list = field(default_factory=list)
    instances: int = 0  # how many instance prims were found referencing it (for reports)

    def __iadd__(self, other: "Site") -> "Site":
        self.meshes += other.meshes
        self.refs += other.refs
        return self

    def key(self) -> str:
        h = hashlib.sha1()
        for o in sorted(self.meshes, key=lambda o: str(o.dest)):
            h.update(f"m {o.dest} {o.key}\n".encode())
        for r in sorted(self.refs, key=lambda r: str(r.dest)):
            h.update(f"r {r.dest} {r.site}\n".encode())
        return h.hexdigest()


@dataclass
class Scene:
    """The subdivision meshes of a stage and where their refined data goes (see :func:`read_scene`)."""

    units: dict  # input digest -> SubdivPrim (None: left alone), in the order found
    top: Site
    sites: dict  # site key -> Site
    left_alone: list  # (path, reason)
    stages: list  # the composed stages the units read from (kept open while they are read)
    instances: list = field(default_factory=list)  # (instance prim path, site key) at the top level
    levels: dict = field(default_factory=dict)  # unit -> its level (with read_scene's level)
    placed: dict = field(default_factory=dict)  # composed mesh path -> (level, source), as read

    def uses(self) -> dict:
        """How many composed meshes (instance proxies of every instance included) each unit refines for."""
        memo: dict = {}

        def count(site) -> dict:
            out: dict = {}
            for o in site.meshes:
                out[o.key] = out.get(o.key, 0) + 1
            for r in site.refs:
                if r.site not in memo:
                    memo[r.site] = count(self.sites[r.site])
                for key, n in memo[r.site].items():
                    out[key] = out.get(key, 0) + n
            return out

        return count(self.top)

    def layout(self, container: Sdf.Path):
        """(targets, references): the output paths of each unit (by key, top-level paths first) and the
        internal references to author ((path, target)), with each prototype's content named
        ``<container>/Prototype_<n>`` (in the order they are reached from the top level)."""
        names, order = {}, []
        todo = [r.site for r in self.top.refs]
        while todo:
            key = todo.pop(0)
            if key in names:
                continue
            names[key] = container.AppendChild(f"Prototype_{len(names) + 1}")
            order.append(key)
            todo += [r.site for r in self.sites[key].refs]
        targets, refs = {}, []
        for o in self.top.meshes:
            targets.setdefault(o.key, []).append(o.dest)
        for r in self.top.refs:
            refs.append((r.dest, names[r.site]))
        for key in order:
            site, path = self.sites[key], names[key]
            for o in site.meshes:
                targets.setdefault(o.key, []).append(o.dest.ReplacePrefix(SITE, path))
            for r in site.refs:
                refs.append((r.dest.ReplacePrefix(SITE, path), names[r.site]))
        return targets, refs, names


@dataclass(frozen=True)
class _Config:
    """A composition of the input: variant selections ((prim path, set, variant), ...) and instances made
    non-instanceable (so that selections below them can be made), authored in a session layer."""

    selections: tuple = ()
    deinstanced: tuple = ()

    def select(self, path, vset, variant, deinstance=()) -> "_Config":
        return _Config(self.selections + ((str(path), vset, variant),),
                       tuple(sorted(set(self.deinstanced) | {str(p) for p in deinstance})))

    def open(self, root_layer: Sdf.Layer, resolver_context=None) -> Usd.Stage:
        """The stage of ``root_layer`` composed in this configuration (a session layer authors it)."""
        session = Sdf.Layer.CreateAnonymous(".usda")
        for path in self.deinstanced:
            Sdf.CreatePrimInLayer(session, path).SetInfo("instanceable", False)
        for path, vset, variant in self.selections:
            Sdf.CreatePrimInLayer(session, path).variantSelections[vset] = variant
        if resolver_context is None:
            return Usd.Stage.Open(root_layer, session, Usd.Stage.LoadAll)
        return Usd.Stage.Open(root_layer, session, resolver_context, Usd.Stage.LoadAll)


class _Explorer:
    """Walks a stage for :func:`read_scene`."""

    def __init__(self, stage, roots, read, all_variants, level=None, level_context=None):
        self.base = stage
        self.roots = roots
        self.read = read
        self.all_variants = all_variants
        self.level, self.level_context = level, level_context
        self.levels: dict = {}
        self.placed: dict = {}
        self._read: dict = {}  # input digest -> SubdivPrim or None
        self.units: dict = {}
        self.sites: dict = {}
        self.left_alone: list = []
        self._stages = {_Config(): stage}
        self._site_of: dict = {}
        self._digest: dict = {}

    # -- configurations --------------------------------------------------------------------------------
    def stage(self, cfg: _Config) -> Usd.Stage:
        if cfg not in self._stages:
            self._stages[cfg] = cfg.open(self.base.GetRootLayer(), self.base.GetPathResolverContext())
        return self._stages[cfg]

    # -- the --prim filter -----------------------------------------------------------------------------
    def related(self, path: Sdf.Path) -> bool:
        return not self.roots or any(path.HasPrefix(r) or r.HasPrefix(path) for r in self.roots)

    def selected(self, path: Sdf.Path) -> bool:
        return not self.roots or any(path.HasPrefix(r) for r in self.roots)

    # -- walking ---------------------------------------------------------------------------------------
    def walk(self, stage, root: Sdf.Path, excluded=frozenset()):
        """(meshes, nested instances, variant-set owners) at or under ``root``, not inside nested instances;
        the prototypes of PointInstancers that are not defined prims (overs, classes) are walked too."""
        meshes, instances, owners, extra = [], [], [], []
        top = stage.GetPrimAtPath(root)
        if not top:
            return meshes, instances, owners

        def visit(start, predicate):
            it = iter(Usd.PrimRange(start, Usd.TraverseInstanceProxies(predicate)))
            for prim in it:
                path = prim.GetPath()
                if path in excluded or not self.related(path):
                    it.PruneChildren()
                    continue
                if prim != top and prim.IsInstance():
                    instances.append(prim)
                    it.PruneChildren()
                    continue
                if self.all_variants and prim.HasVariantSets():
                    owners.append(prim)
                if prim.IsA(UsdGeom.PointInstancer):
                    for target in UsdGeom.PointInstancer(prim).GetPrototypesRel().GetForwardedTargets():
                        proto = stage.GetPrimAtPath(target)
                        if proto and not proto.IsDefined() or proto and proto.IsAbstract():
                            extra.append(proto)
                if prim.IsA(UsdGeom.Mesh) and self.selected(path):
                    meshes.append(prim)

        visit(top, Usd.PrimDefaultPredicate)
        seen = set()
        for proto in extra:
            if proto.GetPath() not in seen and not any(proto.GetPath().HasPrefix(p) for p in seen):
                seen.add(proto.GetPath())
                visit(proto, Usd.PrimIsActive & Usd.PrimIsLoaded)
        return meshes, instances, owners

    def unit(self, prim) -> str | None:
        """The unit of a mesh: its input digest (read once per digest), with its level appended when levels
        are chosen per mesh (``level``: meshes with equal inputs and different levels refine apart); None
        when it is left alone."""
        digest = input_fingerprint(prim)
        if digest not in self._read:
            sp = self.read(prim)
            self._read[digest] = sp
            if sp is None:
                scheme = prim.GetAttribute("subdivisionScheme").Get()
                self.left_alone.append((str(prim.GetPath()), "empty mesh" if scheme != "none"
                                        else "subdivisionScheme none"))
                self.units[digest] = None
        sp = self._read[digest]
        if sp is None:
            return None
        key = digest
        if self.level is not None:
            level, source = self.level(prim, sp)
            self.placed[str(prim.GetPath())] = (level, source)
            key = f"{digest}@{level}"
            self.levels[key] = level
            if key not in self.units and str(prim.GetPath()) != sp.path:
                # the same input at another level: a unit of its own, named after the mesh it was met at
                sp = dataclasses.replace(sp, path=str(prim.GetPath()), prim=prim)
        self.units.setdefault(key, sp)
        return key

    def subtree_digest(self, cfg, root: Sdf.Path) -> str:
        """A digest of every selected mesh at or under ``root`` (through instances too) in ``cfg``."""
        stage = self.stage(cfg)
        h = hashlib.sha1()
        top = stage.GetPrimAtPath(root)
        if top:
            for prim in Usd.PrimRange(top, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
                if prim.IsA(UsdGeom.Mesh) and self.selected(prim.GetPath()):
                    h.update(f"{prim.GetPath()} {input_fingerprint(prim)}\n".encode())
        return h.hexdigest()

    # -- exploring -------------------------------------------------------------------------------------
    @staticmethod
    def dest(path: Sdf.Path, site_root: Sdf.Path, dest_root: Sdf.Path, fixed) -> Sdf.Path:
        """The output path of composed ``path`` in a site rooted at ``site_root`` (written at ``dest_root``),
        inside the variants ``fixed`` ((owner path, set, variant), ...) selects."""
        chosen: dict = {}
        for owner, vset, variant in fixed:
            chosen.setdefault(owner, []).append((vset, variant))
        cur = dest_root
        for vset, variant in chosen.get(str(site_root), ()):
            cur = cur.AppendVariantSelection(vset, variant)
        for prefix in path.GetPrefixes()[len(site_root.GetPrefixes()):]:
            cur = cur.AppendChild(prefix.name)
            for vset, variant in chosen.get(str(prefix), ()):
                cur = cur.AppendVariantSelection(vset, variant)
        return cur

    def explore(self, cfg, site_root, dest_root, fixed, root, excluded=frozenset()) -> Site:
        stage = self.stage(cfg)
        meshes, instances, owners = self.walk(stage, root, excluded)
        done = {(o, s) for o, s, _ in fixed}
        for owner in owners:
            opath = owner.GetPath()
            for vset in owner.GetVariantSets().GetNames():
                if (str(opath), vset) in done:
                    continue
                variants = owner.GetVariantSet(vset).GetVariantNames()
                deinstance = [p.GetPath() for p in _instance_ancestors(owner)]
                configs = [cfg.select(opath, vset, v, deinstance) for v in variants]
                if len({self.subtree_digest(c, opath) for c in configs}) < 2:
                    continue  # no variant of this set changes a mesh
                site = Site()
                for v, c in zip(variants, configs):
                    site += self.explore(c, site_root, dest_root, fixed + ((str(opath), vset, v),), opath)
                site += self.explore(cfg, site_root, dest_root, fixed, root, excluded | {opath})
                return site
        site = Site()
        for prim in meshes:
            key = self.unit(prim)
            if key is not None:
                site.meshes.append(Occurrence(key, self.dest(prim.GetPath(), site_root, dest_root, fixed),
                                              str(prim.GetPath()), cfg))
        for prim in instances:
            key = self.instance_site(cfg, prim)
            if key is not None:
                site.refs.append(SiteRef(self.dest(prim.GetPath(), site_root, dest_root, fixed), key,
                                         str(prim.GetPath()), cfg, str(prim.GetPrototype().GetPath())))
        return site

    def instance_site(self, cfg, inst) -> str | None:
        """The site key of an instance's prototype (its refined content), explored once per prototype; None
        when nothing in it is refined."""
        path = inst.GetPath()
        scope = () if self.selected(path) else tuple(str(r) for r in self.roots if r.HasPrefix(path))
        cache = (cfg, str(inst.GetPrototype().GetPath()), scope,
                 self.level_context(inst) if self.level_context is not None else None)
        if cache not in self._site_of:
            site_cfg = cfg
            if self.all_variants:  # selections below the instance need it (and its ancestors) composed in place
                outer = [p.GetPath() for p in _instance_ancestors(inst)]
                site_cfg = _Config(cfg.selections, tuple(sorted(set(cfg.deinstanced) | {str(p) for p in outer})))
            site = self.explore(site_cfg, path, SITE, (), path)
            key = site.key() if site.meshes or site.refs else None
            if key is not None:
                self.sites.setdefault(key, site)
            self._site_of[cache] = key
        key = self._site_of[cache]
        if key is not None:
            self.sites[key].instances += 1
        return key


def _instance_ancestors(prim: Usd.Prim) -> list:
    """The instances whose prototypes hold ``prim`` (outermost first): the ancestors an instance proxy is
    composed under."""
    out = []
    parent = prim.GetParent()
    while parent and not parent.IsPseudoRoot():
        if parent.IsInstance():
            out.append(parent)
        parent = parent.GetParent()
    return out[::-1]


def read_scene(stage: Usd.Stage, prim_paths=None, *, read, all_variants: bool = False, where: str = "",
               level=None, level_context=None) -> Scene:
    """Every mesh at or under ``prim_paths`` (default: the whole stage), inside instances and PointInstancer
    prototypes too, read with ``read(prim) -> SubdivPrim | None`` once per distinct input
    (:func:`input_fingerprint`), and where its refined data goes:

    * a mesh outside instances: at its own path;
    * a mesh inside a scene-graph instance: in its prototype's refined content (a :class:`Site`, its paths
      under :data:`SITE`), which the instance references; nested instances reference their own prototype's
      content from inside it. Prototypes are explored once each; contents that are equal are one site;
    * with ``all_variants``: every variant of every variant set that changes a mesh (nested sets too) is
      composed and read, and its meshes go inside the same variant set and variant in the output paths.

    ``level``: ``level(prim, sp) -> (level, source)`` for each composed mesh read (levels chosen per mesh):
    a unit is then a distinct input at one level (:attr:`Scene.levels`, :attr:`Scene.placed`);
    ``level_context(instance prim)``: what else the levels inside an instance depend on (a hashable value),
    so that instances of one prototype whose levels may differ are read apart.
    """
    roots = check_roots(stage, prim_paths, where)
    explorer = _Explorer(stage, roots, read, all_variants, level, level_context)
    top = explorer.explore(_Config(), Sdf.Path.absoluteRootPath, Sdf.Path.absoluteRootPath, (),
                           Sdf.Path.absoluteRootPath)
    scene = Scene(explorer.units, top, explorer.sites, explorer.left_alone, list(explorer._stages.values()),
                  levels=explorer.levels, placed=explorer.placed)
    scene.instances = [(r.composed, r.site) for r in top.refs]
    return scene


__all__ = ["SITE", "Occurrence", "Scene", "Site", "SiteRef", "input_fingerprint", "read_scene", "skinned"]
