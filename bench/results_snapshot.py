"""Bitwise snapshots of results, to prove that a change which must not change results (a move of modules, a
refactoring) did not.

    python bench/results_snapshot.py write OUT_DIR [--lib PATH | --commit REV] [--levels 1,2,3] [--device cpu]
    python bench/results_snapshot.py compare A_DIR B_DIR

``write`` refines every OBJ mesh of ``--meshes`` (default /work/shared/meshes: basic/, opensubdiv-shapes/) and of
scenes/ with both schemes (Catmull-Clark on any mesh; Loop on every mesh too: polygon meshes are fan-triangulated)
and both rule sets (piecewise-smooth, opensubdiv), the file's own tags (``interpolateboundary``,
``creasemethod``) as options, at every level of ``--levels``, through the public API only
(``warp_subdiv.Refiner`` / ``Refined``, ``warp_subdiv.LimitSurface``; OBJ files are read with the project's
reader, ``warp_subdiv.io.obj.read_obj`` or else ``warp_subdiv.objio.read_obj``). It saves in ``arrays.npz``,
keyed ``group/mesh/scheme/rules/L<level>/<field>``: the refined points (their exact float bits), face counts
and indices, limit points and normals; per mesh/scheme/rules ``.../surface/<field>``: LimitSurface points,
derivatives and normals at a few (face, u, v) of every control face; per mesh ``group/mesh/input/<field>``: the
mesh as read. A request the library refuses is saved as the exception's type name (``.../error``), the warnings
it gave as their categories' names (``.../warnings``), so a change in what is accepted or warned about shows up
too. It then bakes every scene of scenes/ (.usda, and the .obj) with the command line (``python -m warp_subdiv
refine IN -o OUT --levels 2 --device D``, run in a temporary folder so that the library under test is the one
imported) and saves each output file's text under ``layers/``, normalised only where it legitimately differs
between runs: the sublayer path back to the input (relative to the output's folder) and the ``version`` that the
layer records; a bake that fails is saved as its exit status and its error lines.

``--lib PATH`` puts PATH first on ``sys.path`` (and on the command line's PYTHONPATH) so that an exported older
checkout is snapshotted (``benchutil.export_commit``); ``--commit REV`` exports REV itself and removes the
export afterwards.

``compare`` prints every difference (key, max abs diff, number of differing elements, dtypes and shapes; for
layers the number of differing lines and the first), exit status 1 on any difference; otherwise one line that
says how many arrays and layers were compared, exit status 0.

Typical use around a move (HEAD before, the work tree after)::

    python bench/results_snapshot.py write /tmp/snap/base --commit HEAD
    python bench/results_snapshot.py write /tmp/snap/check
    python bench/results_snapshot.py compare /tmp/snap/base /tmp/snap/check
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED_MESHES = "/work/shared/meshes"
MESH_GROUPS = ("basic", "opensubdiv-shapes")  # folders of --meshes; scenes/ of the repository comes on top
SCHEMES = ("catmull-clark", "loop")
RULES = ("piecewise-smooth", "opensubdiv")
BAKE_LEVELS = 2
# (u, v) inside the first half-unit tile: valid on a quad, a triangle (u + v <= 1) and tile 0 of the sub-face
# layout of n-gons and of Loop polygons (warp_subdiv.limit's parameterisation)
SURFACE_UV = np.array([[0.0, 0.0], [0.25, 0.0], [0.1, 0.3], [0.2, 0.2], [0.45, 0.05], [0.0, 0.4]])
ARRAYS, MANIFEST, LAYERS = "arrays.npz", "manifest.json", "layers"


# ----------------------------------------------------------------------------------------------- write
def import_library(lib: str | None):
    """Import warp_subdiv (from ``lib`` when given, checked) with Warp quiet; (module, read_obj, reader name)."""
    if lib:
        sys.path.insert(0, os.path.abspath(lib))
    import warp as wp

    wp.config.log_level = 30
    wp.config.quiet = True
    import warp_subdiv

    where = os.path.abspath(warp_subdiv.__file__)
    if lib and not where.startswith(os.path.abspath(lib) + os.sep):
        sys.exit(f"imported {where}, not the library under {lib}")
    try:
        from warp_subdiv.io.obj import read_obj

        reader = "warp_subdiv.io.obj.read_obj"
    except ModuleNotFoundError as exc:
        if exc.name not in ("warp_subdiv.io", "warp_subdiv.io.obj"):
            raise
        from warp_subdiv.objio import read_obj

        reader = "warp_subdiv.objio.read_obj"
    return warp_subdiv, read_obj, reader


def mesh_files(meshes_root: str) -> list:
    """(group, name, path) of every OBJ file, in a fixed order."""
    out = []
    for group, folder in [(g, os.path.join(meshes_root, g)) for g in MESH_GROUPS] + [("scenes",
                                                                                    os.path.join(ROOT, "scenes"))]:
        if not os.path.isdir(folder):
            sys.exit(f"no folder {folder}")
        for name in sorted(os.listdir(folder)):
            if name.endswith(".obj"):
                out.append((group, name[:-4], os.path.join(folder, name)))
    return out


def _error(exc: BaseException) -> np.ndarray:
    return np.array(type(exc).__name__)


def _warned(caught) -> np.ndarray | None:
    names = sorted({w.category.__name__ for w in caught})
    return np.array(names) if names else None


def _call(results: dict, key: str, fn):
    """fn() with its warnings recorded under key/warnings; its exception's type name under key/error."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            value = fn()
        except Exception as exc:  # noqa: BLE001  (a refusal is a result: its type is recorded and compared)
            value = None
            results[key + "/error"] = _error(exc)
    names = _warned(caught)
    if names is not None:
        results[key + "/warnings"] = names
    return value


def mesh_inputs(results: dict, key: str, obj) -> None:
    """The mesh as read (what the reader made of the file, tags included) and the options its tags ask for."""
    mesh = obj.mesh
    for field in ("points", "face_vertex_counts", "face_vertex_indices", "creases", "crease_sharpness", "corners",
                  "corner_sharpness", "concave", "holes", "normal_vertices", "normal_vectors"):
        value = getattr(mesh, field, None)
        if value is not None:
            results[f"{key}/input/{field}"] = np.asarray(value)
    results[f"{key}/input/options"] = np.array(json.dumps(dict(obj.options), sort_keys=True))


def refine_cases(ws, read_obj, meshes_root: str, levels: list, device: str, results: dict) -> int:
    """Every mesh x scheme x rules x level into results; the number of refinement cases."""
    cases = 0
    for group, name, path in mesh_files(meshes_root):
        base = f"{group}/{name}"
        obj = _call(results, base + "/read", lambda: read_obj(path))
        if obj is None:
            continue
        mesh_inputs(results, base, obj)
        file_options = {k: v for k, v in dict(obj.options).items() if k in ("boundary", "crease_method")}
        for scheme in SCHEMES:
            for rules in RULES:
                options = dict(scheme=scheme, rules=rules, **file_options)
                for level in levels:
                    key = f"{base}/{scheme}/{rules}/L{level}"
                    cases += 1
                    refined = _call(results, key, lambda: ws.Refiner(mesh=obj.mesh, levels=level, device=device,
                                                                     **options).refine())
                    if refined is None:
                        continue
                    results[key + "/points"] = np.asarray(refined.points)
                    results[key + "/face_vertex_counts"] = np.asarray(refined.face_vertex_counts)
                    results[key + "/face_vertex_indices"] = np.asarray(refined.face_vertex_indices)
                    for field in ("limit_points", "limit_normals"):
                        value = _call(results, f"{key}/{field}", getattr(refined, field))
                        if value is not None:
                            results[f"{key}/{field}"] = np.asarray(value)
                key = f"{base}/{scheme}/{rules}/surface"
                surface = _call(results, key, lambda: ws.LimitSurface(obj.mesh, device=device, **options))
                if surface is None:
                    continue
                faces = np.flatnonzero(~np.asarray(surface.holes, dtype=bool))
                f = np.repeat(faces, len(SURFACE_UV))
                uv = np.tile(SURFACE_UV, (len(faces), 1))
                ev = _call(results, key + "/evaluate",
                           lambda: surface.evaluate(f, uv[:, 0], uv[:, 1], derivatives=2))
                if ev is not None:
                    results[key + "/faces"] = f
                    for field in ("points", "du", "dv", "normals", "duu", "duv", "dvv"):
                        results[f"{key}/{field}"] = np.asarray(getattr(ev, field))
    return cases


def bake_inputs() -> list:
    """The scenes the command line bakes: every .usda and .obj of scenes/ (OBJ out for OBJ in)."""
    folder = os.path.join(ROOT, "scenes")
    return [os.path.join(folder, n) for n in sorted(os.listdir(folder)) if n.endswith((".usda", ".obj"))]


def normalise_layer(text: str, input_path: str, out_dir: str) -> str:
    """The output text with what differs between runs of the same library replaced: the asset paths that lead
    back to the input (written relative to the output's folder) or into the temporary output folder, and the
    library version the layer records."""
    def asset(m):
        path = m.group(1)
        full = os.path.normpath(os.path.join(out_dir, path))
        if full == os.path.normpath(input_path):
            return "@<input>@"
        if full.startswith(out_dir + os.sep):
            return "@<out>/" + os.path.relpath(full, out_dir) + "@"
        return m.group(0)

    text = re.sub(r"@([^@\n]+)@", asset, text)
    return re.sub(r'^(\s*string version = )"[^"]*"$', r'\1"<version>"', text, flags=re.M)


def bake(path: str, device: str, env: dict) -> str:
    """Bake one scene with the command line in a fresh temporary folder; the normalised output text, or the exit
    status and the error lines."""
    out_dir = os.path.realpath(tempfile.mkdtemp(prefix="wsnap_bake_"))
    try:
        out = os.path.join(out_dir, os.path.basename(path))
        cmd = [sys.executable, "-m", "warp_subdiv", "refine", path, "-o", out, "--levels", str(BAKE_LEVELS),
               "--device", device, "--quiet"]
        proc = subprocess.run(cmd, cwd=out_dir, env=env, capture_output=True, text=True, timeout=300)
        # Warp's own start-up lines (e.g. no CUDA driver) depend on the machine, not on the library
        errs = [line.replace(path, "<input>").replace(out_dir, "<out>") for line in proc.stderr.splitlines()
                if line.strip() and not line.startswith("Warp ")]
        if proc.returncode != 0:
            return f"# bake failed: exit status {proc.returncode}\n" + "\n".join(errs) + "\n"
        with open(out, encoding="utf-8") as fh:
            text = normalise_layer(fh.read(), path, out_dir)
        return ("# stderr: " + "\n# stderr: ".join(errs) + "\n" if errs else "") + text
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)


def library_where(env: dict) -> str:
    """Which warp_subdiv ``python -m warp_subdiv`` imports with this environment (run where the bakes run)."""
    cwd = tempfile.mkdtemp(prefix="wsnap_where_")
    try:
        code = "import importlib.util as u; print(u.find_spec('warp_subdiv').origin)"
        return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                              check=True).stdout.strip()
    finally:
        shutil.rmtree(cwd, ignore_errors=True)


def write(args) -> int:
    t0 = time.perf_counter()
    lib, commit = args.lib, None
    if args.commit:
        sys.path.insert(1, HERE)
        from benchutil import export_commit

        lib, commit = export_commit(args.commit, prefix="wsnap_lib_")
    try:
        return _write(args, lib, commit, t0)
    finally:
        if args.commit:
            shutil.rmtree(lib, ignore_errors=True)


def _write(args, lib, commit, t0) -> int:
    env = dict(os.environ)
    if lib:
        lib = os.path.abspath(lib)
        env["PYTHONPATH"] = lib + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    levels = [int(x) for x in args.levels.split(",")]
    os.makedirs(args.out_dir, exist_ok=True)
    leftover = set(os.listdir(args.out_dir)) - {ARRAYS, MANIFEST, LAYERS}
    if leftover:
        sys.exit(f"{args.out_dir} holds other files than a snapshot's ({sorted(leftover)[:3]}): give a new folder")
    layers_dir = os.path.join(args.out_dir, LAYERS)
    shutil.rmtree(layers_dir, ignore_errors=True)
    os.makedirs(layers_dir)

    # the bakes (subprocesses, mostly start-up) run beside the in-process refinement
    scenes = bake_inputs()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        where = pool.submit(library_where, env)
        baked = [pool.submit(bake, p, args.device, env) for p in scenes]
        ws, read_obj, reader = import_library(lib)
        results: dict = {}
        t_refine = time.perf_counter()
        cases = refine_cases(ws, read_obj, args.meshes, levels, args.device, results)
        t_refine = time.perf_counter() - t_refine
        cli_lib = where.result()
        layers = {os.path.basename(p): f.result() for p, f in zip(scenes, baked)}
    if lib and not cli_lib.startswith(lib + os.sep):
        sys.exit(f"the command line imported {cli_lib}, not the library under {lib}")

    np.savez(os.path.join(args.out_dir, ARRAYS), **dict(sorted(results.items())))
    for name, text in layers.items():
        with open(os.path.join(layers_dir, name + ".txt"), "w", encoding="utf-8") as fh:
            fh.write(text)
    import warp

    errors = sorted(k for k in results if k.endswith("/error"))
    failed = sorted(n for n, t in layers.items() if t.startswith("# bake failed"))
    manifest = {
        "library": os.path.dirname(os.path.abspath(ws.__file__)), "command_line_library": cli_lib,
        "commit": commit, "obj_reader": reader, "device": args.device, "levels": levels,
        "bake_levels": BAKE_LEVELS, "meshes": args.meshes, "cases": cases, "arrays": len(results),
        "layers": len(layers), "refused": errors, "bakes_failed": failed,
        "versions": {"python": platform.python_version(), "numpy": np.__version__, "warp": warp.__version__,
                     "warp_subdiv": getattr(ws, "__version__", None)},
        "refine_s": round(t_refine, 2), "wall_s": round(time.perf_counter() - t0, 2),
    }
    with open(os.path.join(args.out_dir, MANIFEST), "w", encoding="utf-8") as fh:
        json.dump(manifest, fh, indent=1)
    print(f"wrote {args.out_dir}: {cases} refinement cases ({len(results)} arrays, {len(errors)} refusals) and "
          f"{len(layers)} scene bakes ({len(failed)} failed) of warp_subdiv at {manifest['library']} in "
          f"{manifest['wall_s']:.1f} s")
    return 0


# --------------------------------------------------------------------------------------------- compare
def _describe(a: np.ndarray) -> str:
    return f"{a.dtype}{list(a.shape)}"


def array_difference(a: np.ndarray, b: np.ndarray) -> str | None:
    """None when a and b are the same bits (dtype, shape and bytes); else what differs."""
    if a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes():
        return None
    shapes = f"{_describe(a)} vs {_describe(b)}"
    if a.shape != b.shape or a.dtype.kind not in "biuf" or b.dtype.kind not in "biuf":
        if a.dtype.kind == "U" and b.dtype.kind == "U":
            return f"{a.tolist()!r} vs {b.tolist()!r}"
        return f"{shapes}"
    x, y = a.astype(np.float64), b.astype(np.float64)
    same = (x == y) | (np.isnan(x) & np.isnan(y))
    if a.dtype.kind == "f" and b.dtype.kind == "f" and a.dtype == b.dtype:
        same &= (a.view(f"u{a.itemsize}") == b.view(f"u{b.itemsize}")) | np.isnan(x)  # -0.0 vs 0.0
    finite = np.isfinite(x) & np.isfinite(y)
    diff = float(np.max(np.abs(x - y)[finite & ~same])) if np.any(finite & ~same) else float("nan")
    return f"max abs diff {diff:.6g}, {int(np.sum(~same))} of {a.size} elements differ, {shapes}"


def compare(args) -> int:
    diffs = []
    manifests = []
    for d in (args.a_dir, args.b_dir):
        try:
            with open(os.path.join(d, MANIFEST), encoding="utf-8") as fh:
                manifests.append(json.load(fh))
        except OSError as exc:
            sys.exit(f"{d}: not a snapshot ({exc.strerror})")
    ma, mb = manifests
    for field in ("device", "levels", "bake_levels", "versions"):
        if ma.get(field) != mb.get(field):
            print(f"note: {field} differs ({ma.get(field)} vs {mb.get(field)}): the snapshots are not comparable "
                  f"runs of the same set-up")
    with np.load(os.path.join(args.a_dir, ARRAYS), allow_pickle=False) as fa, \
            np.load(os.path.join(args.b_dir, ARRAYS), allow_pickle=False) as fb:
        ka, kb = set(fa.files), set(fb.files)
        for key in sorted(ka | kb):
            if key not in kb:
                diffs.append(f"{key}: only in A ({_describe(fa[key])})")
            elif key not in ka:
                diffs.append(f"{key}: only in B ({_describe(fb[key])})")
            else:
                why = array_difference(fa[key], fb[key])
                if why:
                    diffs.append(f"{key}: {why}")
        arrays = len(ka & kb)
    la = set(os.listdir(os.path.join(args.a_dir, LAYERS)))
    lb = set(os.listdir(os.path.join(args.b_dir, LAYERS)))
    for name in sorted(la | lb):
        if name not in lb or name not in la:
            diffs.append(f"{LAYERS}/{name}: only in {'A' if name in la else 'B'}")
            continue
        texts = []
        for d in (args.a_dir, args.b_dir):
            with open(os.path.join(d, LAYERS, name), encoding="utf-8") as fh:
                texts.append(fh.read().splitlines())
        ta, tb = texts
        if ta != tb:
            changed = [i for i in range(max(len(ta), len(tb)))
                       if i >= len(ta) or i >= len(tb) or ta[i] != tb[i]]
            i = changed[0]
            first_a = ta[i][:100] if i < len(ta) else "<end>"
            first_b = tb[i][:100] if i < len(tb) else "<end>"
            diffs.append(f"{LAYERS}/{name}: {len(changed)} lines differ ({len(ta)} vs {len(tb)} lines), first at "
                         f"line {i + 1}: {first_a!r} vs {first_b!r}")
    layers = len(la & lb)
    for line in diffs:
        print(line)
    where = f"{ma.get('library')} vs {mb.get('library')}"
    if diffs:
        print(f"DIFFERENT: {len(diffs)} differences in {arrays} arrays and {layers} layers compared ({where})")
        return 1
    print(f"identical: {arrays} arrays ({ma.get('cases')} refinement cases) and {layers} layers compared bitwise "
          f"({where})")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    w = sub.add_parser("write", help="compute and save a snapshot of results")
    w.add_argument("out_dir")
    src = w.add_mutually_exclusive_group()
    src.add_argument("--lib", help="import warp_subdiv from this folder (e.g. a commit exported with "
                                   "benchutil.export_commit) instead of the installed one")
    src.add_argument("--commit", help="export this commit's library (git archive) and snapshot it")
    w.add_argument("--levels", default="1,2,3", help="refinement levels, comma separated (default 1,2,3)")
    w.add_argument("--device", default="cpu", help="Warp device of every evaluation and bake (default cpu)")
    w.add_argument("--meshes", default=SHARED_MESHES,
                   help=f"folder holding {' and '.join(MESH_GROUPS)}/ (default {SHARED_MESHES})")
    w.add_argument("--jobs", type=int, default=2, help="scene bakes run at once (default 2)")
    c = sub.add_parser("compare", help="compare two snapshots bitwise; exit status 1 on any difference")
    c.add_argument("a_dir")
    c.add_argument("b_dir")
    args = p.parse_args(argv)
    return write(args) if args.command == "write" else compare(args)


if __name__ == "__main__":
    sys.exit(main())
