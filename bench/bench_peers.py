"""warp-subdiv side by side with the libraries a user would pick instead, in one run, with ratios.

    python bench/bench_peers.py --commit HEAD --peers-python /tmp/peers/bin/python --json out/bench_peers.json
    python bench/bench_peers.py --quick            # levels 1-2, seconds: CI smoke test (missing peers skipped)
    python bench/bench_peers.py --profile loop:icosphere_5120tri:6   # cProfile of one ws.refine, then exit
    python bench/bench_peers.py --report out/bench_peers.json       # print a saved run's report again

Results and their analysis: bench/PEERS.md. ``--commit REV`` measures warp_subdiv/ and kernels/ of a commit
(``git archive`` into a temporary folder) instead of a working tree that others may be editing meanwhile.

Two interpreters may take part: ``--ours-python`` (default: this one) runs warp-subdiv (numpy, warp-lang) and
the OpenSubdiv C++ peer (``peers/osd_peer.py``); ``--peers-python`` (default: ``$WS_PEERS_PYTHON``, else this
one) runs the Python peers, so that they can live in their own virtual environment:

    python3 -m venv /tmp/peers && /tmp/peers/bin/pip install numpy libigl pyvista vtk pymeshlab trimesh \\
        pygel3d networkx scipy

A peer that is not installed is reported as such (and left out silently with ``--quick``); the OpenSubdiv peer
is skipped when ``peers/osd_peer.py`` finds no binary and cannot build one (``peers/install_osd.sh``).

What is measured. "End to end" (e2e) is the same for every tool: numpy points (n, 3) float64 and faces (F, k)
in, refined numpy points and faces out, including every conversion the tool needs (building its mesh object
from the arrays, reading its result back into arrays), excluding file I/O and imports. Each (tool, mesh,
level) runs in a fresh subprocess, so its peak resident memory (VmHWM; for OpenSubdiv ``ru_maxrss`` of the
C++ process) is its own; the parent kills a subprocess that runs past ``--timeout`` or whose process tree
grows past ``--mem-limit-gib``, and then skips that tool's higher levels on that mesh. Timings are the best of
``--reps`` repetitions in that subprocess (fewer when the repetitions of one configuration have already
taken ``--rep-budget`` seconds); the spread (slowest / fastest - 1) is reported as a noise indicator.

* warp-subdiv   e2e: ``ws.Mesh(points, counts, indices)`` + ``ws.refine(mesh, L, scheme, device="cpu")``,
                after one untimed level-1 refine of a tiny mesh has loaded Warp's kernel module; then
                ``Refiner(...)`` build, ``topology()``, the first ``evaluate`` (table upload, buffers) and the
                best of ``--frames`` further ``evaluate`` calls (numpy in and out; each with other points) and
                ``evaluate_device`` calls (no copy back to numpy).
* libigl        ``igl.loop(V, F, L)``.
* vtk           pyvista ``PolyData.from_regular_faces`` + ``subdivide(L, "loop")`` (vtkLoopSubdivisionFilter)
                + ``points`` / ``regular_faces``.
* pymeshlab     ``Mesh`` + ``meshing_surface_subdivision_loop(iterations=L, threshold=0%)`` (the default
                threshold of 1% leaves short edges unsplit, which is not uniform refinement) or
                ``meshing_surface_subdivision_catmull_clark(iterations=L)``; ``vertex_matrix`` and
                ``face_matrix`` (Loop) or ``polygonal_face_list`` (Catmull-Clark, quads).
* trimesh       ``trimesh.remesh.subdivide_loop(V, F, iterations=L)``.
* pygel3d       ``Manifold.from_triangles`` (Loop) or ``add_face`` per quad + ``stitch`` (Catmull-Clark),
                ``loop_subdivide`` / ``cc_subdivide`` L times, ``cleanup``, ``positions`` and a
                ``circulate_face`` per face (PyGEL3D has no bulk face export).
* opensubdiv    ``osd_peer.bench`` (C++, OpenSubdiv 3.5, single-threaded, float32; see peers/osd/osd_peer.cpp):
                topology = TopologyRefinerFactory::Create + RefineUniform(L); table-free = topology +
                PrimvarRefiner::Interpolate level by level; per-level = topology + StencilTableFactory (one
                table per level) + Osd::CpuEvaluator::EvalStencils level by level; factorised = topology +
                one table of level L over the control vertices + one EvalStencils. Each phase is the best of
                ``--reps`` inside the C++ process; the e2e figures add the phases' best times. They leave out
                reading the face list back into arrays (which ours and the Python peers include).

"core" is the tool's subdivision call alone (its own best over the repetitions; for warp-subdiv ``ws.refine``
without building the ``ws.Mesh``); "peer / ours" = peer e2e / warp-subdiv e2e of the same mesh and level (> 1:
warp-subdiv is faster).

Memory-traffic floor of an evaluation: every level reads its parent's points once and writes its own once
(float32 xyz, 12 bytes a point), sum over the levels, divided by the copy bandwidth measured here (``np.copyto``
of a 1 GiB float32 array, (read + write) bytes / time, best of 3, in its own subprocess, at the start and the end
of the run; the higher of the two is used).

Exit status 1 when a warp-subdiv worker crashed; a peer failing, timing out or running out of memory is
reported in the output and is not a failure of the benchmark.
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import shlex
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from benchutil import (  # noqa: E402 (the scripts run as files; their folder holds the shared helpers)
    export_commit, mem_available_bytes, parse_levels, peak_rss_bytes, quiet_warp, run_child)
MESH_DIR = os.path.join(HERE, "meshes")
MARK = "PEERS_RESULT "
MIB = 2**20

MESHES = {
    # name: (file, scheme)
    "icosphere_5120tri": ("icosphere_5120tri.obj", "loop"),
    "torus_100x50_5000quad": ("torus_100x50_5000quad.obj", "catmull-clark"),
    "cube64_noisy": ("cube64_noisy.obj", "catmull-clark"),
}

# Python peers: import name, distributions whose versions are reported, schemes, how they are called
PEERS = {
    "libigl": {"module": "igl", "dists": ["libigl"], "schemes": ["loop"], "call": "igl.loop"},
    "vtk": {"module": "pyvista", "dists": ["vtk", "pyvista"], "schemes": ["loop"],
            "call": "pyvista subdivide(L, 'loop') = vtkLoopSubdivisionFilter"},
    "pymeshlab": {"module": "pymeshlab", "dists": ["pymeshlab"], "schemes": ["loop", "catmull-clark"],
                  "call": "meshing_surface_subdivision_loop / _catmull_clark"},
    "trimesh": {"module": "trimesh", "dists": ["trimesh", "networkx", "scipy"], "schemes": ["loop"],
                "call": "trimesh.remesh.subdivide_loop"},
    "pygel3d": {"module": "pygel3d.hmesh", "dists": ["PyGEL3D"], "schemes": ["loop", "catmull-clark"],
                "call": "hmesh.loop_subdivide / cc_subdivide"},
}
OSD_PATHS = [  # (key, label)
    ("table_free", "OpenSubdiv topology + table-free interpolate"),
    ("per_level", "OpenSubdiv topology + per-level stencils + CpuEvaluator"),
    ("factorized", "OpenSubdiv topology + factorised stencils + CpuEvaluator"),
]


# ------------------------------------------------------------------------------------------------ common
def load_obj(path):
    """(points (n, 3) float64, faces (F, k) int64) of an OBJ whose faces all have k vertices (no I/O timing)."""
    import numpy as np

    pts, faces = [], []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.startswith("v "):
                pts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                faces.append([int(tok.split("/")[0]) - 1 for tok in line.split()[1:]])
    sizes = {len(f) for f in faces}
    if len(sizes) != 1:
        raise ValueError(f"{path}: faces of mixed sizes {sorted(sizes)}")
    return np.asarray(pts, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def _shape_stats(points) -> dict:
    """Cheap fingerprint of a refined surface, to check that every tool computed the same one."""
    import numpy as np

    p = np.asarray(points, dtype=np.float64)
    return {"mean_norm": float(np.linalg.norm(p, axis=1).mean()), "max_norm": float(np.linalg.norm(p, axis=1).max())}


def _timed_reps(fn, reps: int, budget_s: float):
    """Run fn() up to reps times (fewer once budget_s has been spent); returns (times, phases, first result).

    fn returns (phases dict, result); the result of a repetition is dropped before the next one starts."""
    times, phases, first = [], [], None
    spent = 0.0
    for i in range(reps):
        gc.collect()
        c = time.process_time()
        t = time.perf_counter()
        ph, res = fn()
        dt = time.perf_counter() - t
        ph["cpu_s"] = time.process_time() - c  # this process's CPU time: less sensitive to other jobs
        times.append(dt)
        phases.append(ph)
        if first is None:
            first = res
        del res
        spent += dt
        if spent > budget_s and i + 1 < reps:
            break
    return times, phases, first


def _best_phases(phases: list) -> dict:
    return {k: min(p[k] for p in phases) for k in phases[0]}


# ------------------------------------------------------------------------------------------------ peers
def _peer_libigl(V, F, L, scheme):
    import igl

    t0 = time.perf_counter()
    nv, nf = igl.loop(V, F, L)
    t1 = time.perf_counter()
    return {"core_s": t1 - t0}, (nv, nf)


def _peer_vtk(V, F, L, scheme):
    import numpy as np
    import pyvista as pv

    t0 = time.perf_counter()
    poly = pv.PolyData.from_regular_faces(V, F)
    t1 = time.perf_counter()
    out = poly.subdivide(L, "loop")
    t2 = time.perf_counter()
    pts = np.asarray(out.points)
    faces = out.regular_faces
    t3 = time.perf_counter()
    return {"in_s": t1 - t0, "core_s": t2 - t1, "out_s": t3 - t2}, (pts, faces)


def _peer_pymeshlab(V, F, L, scheme):
    import numpy as np
    import pymeshlab as pm

    t0 = time.perf_counter()
    ms = pm.MeshSet()
    if scheme == "loop":
        ms.add_mesh(pm.Mesh(V, F.astype(np.int32)))
    else:
        ms.add_mesh(pm.Mesh(V, [f for f in F.astype(np.uint32)]))
    t1 = time.perf_counter()
    if scheme == "loop":
        ms.meshing_surface_subdivision_loop(iterations=L, threshold=pm.PercentageValue(0.0))
    else:
        ms.meshing_surface_subdivision_catmull_clark(iterations=L)
    t2 = time.perf_counter()
    m = ms.current_mesh()
    pts = m.vertex_matrix()
    faces = m.face_matrix() if scheme == "loop" else np.stack(m.polygonal_face_list())
    t3 = time.perf_counter()
    return {"in_s": t1 - t0, "core_s": t2 - t1, "out_s": t3 - t2}, (pts, faces)


def _peer_trimesh(V, F, L, scheme):
    import trimesh

    t0 = time.perf_counter()
    nv, nf = trimesh.remesh.subdivide_loop(V, F, iterations=L)
    return {"core_s": time.perf_counter() - t0}, (nv, nf)


def _peer_pygel3d(V, F, L, scheme):
    import numpy as np
    from pygel3d import hmesh

    t0 = time.perf_counter()
    if scheme == "loop":
        m = hmesh.Manifold.from_triangles(V, F)
    else:  # no polygon constructor: add the faces one by one, then weld the coincident vertices
        m = hmesh.Manifold()
        for f in F:
            m.add_face(V[f])
        hmesh.stitch(m)
        m.cleanup()
    t1 = time.perf_counter()
    step = hmesh.loop_subdivide if scheme == "loop" else hmesh.cc_subdivide
    for _ in range(L):
        step(m)
    t2 = time.perf_counter()
    m.cleanup()
    pts = np.array(m.positions(), copy=True)
    k = F.shape[1]
    faces = np.fromiter((v for f in m.faces() for v in m.circulate_face(f)), dtype=np.int64).reshape(-1, k)
    t3 = time.perf_counter()
    return {"in_s": t1 - t0, "core_s": t2 - t1, "out_s": t3 - t2}, (pts, faces)


PEER_FUNCS = {"libigl": _peer_libigl, "vtk": _peer_vtk, "pymeshlab": _peer_pymeshlab, "trimesh": _peer_trimesh,
              "pygel3d": _peer_pygel3d}


def probe_worker() -> dict:
    """Which peers import here, with versions (run in the peers' interpreter)."""
    import importlib
    from importlib import metadata

    out = {"python": platform.python_version(), "executable": sys.executable, "peers": {}}
    try:
        out["numpy"] = metadata.version("numpy")
    except metadata.PackageNotFoundError:
        out["numpy"] = None
    for name, spec in PEERS.items():
        entry = {}
        try:
            importlib.import_module(spec["module"])
            entry["available"] = True
        except Exception as exc:  # noqa: BLE001 (any import failure means "not available")
            entry["available"] = False
            entry["error"] = f"{type(exc).__name__}: {exc}"[:300]
        versions = {}
        for dist in spec["dists"]:
            try:
                versions[dist] = metadata.version(dist)
            except metadata.PackageNotFoundError:
                versions[dist] = None
        entry["versions"] = versions
        out["peers"][name] = entry
    return out


def peer_worker(args) -> dict:
    import importlib

    file, scheme = MESHES[args.mesh]
    V, F = load_obj(os.path.join(MESH_DIR, file))
    t = time.perf_counter()
    importlib.import_module(PEERS[args.tool]["module"])
    import_s = time.perf_counter() - t
    fn = PEER_FUNCS[args.tool]
    gc.collect()
    res = {"tool": args.tool, "mesh": args.mesh, "scheme": scheme, "level": args.level, "import_s": import_s,
           "baseline_peak_rss": peak_rss_bytes()}
    times, phases, (pts, faces) = _timed_reps(lambda: fn(V, F, args.level, scheme), args.reps, args.rep_budget)
    res.update(e2e_s=min(times), e2e_all=times, phases=_best_phases(phases), num_vertices=int(len(pts)),
               num_faces=int(len(faces)), face_size=int(faces.shape[1]), **_shape_stats(pts))
    res["peak_rss"] = peak_rss_bytes()
    return res


# ------------------------------------------------------------------------------------------------ ours
def _tiny(scheme):
    import numpy as np

    import warp_subdiv as ws

    if scheme == "loop":  # tetrahedron
        p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
        return ws.Mesh(p, [3] * 4, [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3])
    p = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)  # cube
    idx = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]
    return ws.Mesh(p, [4] * 6, idx)


def ours_worker(args) -> dict:
    import numpy as np

    wp = quiet_warp()
    import warp_subdiv as ws

    assert os.path.abspath(ws.__file__).startswith(os.path.abspath(args.lib_root) + os.sep), \
        f"imported {ws.__file__}, not the library under {args.lib_root}"
    wp.init()
    file, scheme = MESHES[args.mesh]
    V, F = load_obj(os.path.join(MESH_DIR, file))
    L, k = args.level, F.shape[1]
    opts = dict(scheme=scheme, device="cpu")
    t = time.perf_counter()
    ws.refine(_tiny(scheme), 1, **opts)  # loads Warp's kernel module (from its cache), untimed
    module_s = time.perf_counter() - t
    rng = np.random.default_rng(0)
    frames = [V + 1e-3 * rng.standard_normal(V.shape) for _ in range(args.frames)]
    gc.collect()
    res = {"tool": "warp-subdiv", "mesh": args.mesh, "scheme": scheme, "level": L, "module_load_s": module_s,
           "baseline_peak_rss": peak_rss_bytes()}

    def e2e():
        t0 = time.perf_counter()
        mesh = ws.Mesh(V, np.full(len(F), k, dtype=np.int32), F.reshape(-1))
        t1 = time.perf_counter()
        r = ws.refine(mesh, L, **opts)
        pts, faces = r.points, r.face_vertex_indices.reshape(-1, k)
        return {"in_s": t1 - t0, "core_s": time.perf_counter() - t1}, (pts, faces)

    times, phases, (pts, faces) = _timed_reps(e2e, args.reps, args.rep_budget)
    res.update(e2e_s=min(times), e2e_all=times, phases=_best_phases(phases), num_vertices=int(len(pts)),
               num_faces=int(len(faces)), face_size=k, **_shape_stats(pts))
    del pts, faces
    gc.collect()
    res["peak_rss_e2e"] = peak_rss_bytes()
    if args.e2e_only:
        res["peak_rss"] = res["peak_rss_e2e"]
        return res

    mesh = ws.Mesh(V, np.full(len(F), k, dtype=np.int32), F.reshape(-1))
    refiner = None

    def build():
        nonlocal refiner
        refiner = None
        gc.collect()
        t0 = time.perf_counter()
        refiner = ws.Refiner(mesh, L, **opts)
        return {"build_s": time.perf_counter() - t0}, None

    btimes, _, _ = _timed_reps(build, args.reps, args.rep_budget)
    res["build_s"], res["build_all"] = min(btimes), btimes
    t = time.perf_counter()
    refiner.topology()
    res["topology_s"] = time.perf_counter() - t
    t = time.perf_counter()
    refiner.evaluate(V)
    res["first_eval_s"] = time.perf_counter() - t
    ev, dev = [], []
    for p in frames:
        t = time.perf_counter()
        refiner.evaluate(p)
        ev.append(time.perf_counter() - t)
    for p in frames:
        t = time.perf_counter()
        refiner.evaluate_device(p)
        wp.synchronize()
        dev.append(time.perf_counter() - t)
    res.update(eval_s=min(ev), eval_all=ev, eval_device_s=min(dev), eval_device_all=dev)
    res["level_vertices"] = [int(refiner.base_num_vertices)] + [int(s.num_rows) for s in refiner.steps]
    res["table_bytes"] = int(refiner.table_bytes())
    res["peak_rss"] = peak_rss_bytes()
    return res


def osd_worker(args) -> dict:
    import numpy as np

    sys.path.insert(0, ROOT)
    from peers import osd_peer

    file, scheme = MESHES[args.mesh]
    if not osd_peer.available():
        return {"tool": "opensubdiv", "skipped": "osd_peer unavailable (peers/install_osd.sh, peers/osd/build.sh)"
                + (": " + osd_peer.build_log()[-300:] if osd_peer.build_log() else "")}
    V, F = load_obj(os.path.join(MESH_DIR, file))
    out = osd_peer.bench(V, np.full(len(F), F.shape[1]), F.reshape(-1), args.level,
                         scheme="catmark" if scheme == "catmull-clark" else "loop", reps=args.reps,
                         budget_mb=args.osd_budget_mb, factorized="last", timeout=args.timeout)
    return {"tool": "opensubdiv", "mesh": args.mesh, "scheme": scheme, "level": args.level, "osd": out,
            "version": osd_peer.version()}


def bandwidth_worker(args) -> dict:
    import numpy as np

    n = int(args.bw_mib * MIB) // 4
    src = np.ones(n, dtype=np.float32)
    dst = np.zeros(n, dtype=np.float32)  # written once, so no page faults are timed
    dst.fill(1.0)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        np.copyto(dst, src)
        times.append(time.perf_counter() - t)
    return {"bytes": 4 * n, "copy_s": times, "bandwidth": 2 * 4 * n / min(times)}


def profile_ours(spec: str, reps_note=True):
    import cProfile
    import pstats

    import numpy as np

    parts = spec.split(":")
    if len(parts) != 3 or parts[1] not in MESHES or not parts[2].isdigit():
        sys.exit(f"--profile wants SCHEME:MESH:LEVEL (MESH one of {', '.join(MESHES)}), got {spec!r}")
    scheme, name, level = parts[0], parts[1], int(parts[2])
    wp = quiet_warp()
    import warp_subdiv as ws

    wp.init()
    V, F = load_obj(os.path.join(MESH_DIR, MESHES[name][0]))
    ws.refine(_tiny(scheme), 1, scheme=scheme, device="cpu")
    t = time.perf_counter()
    ws.refine(ws.Mesh(V, np.full(len(F), F.shape[1]), F.reshape(-1)), level, scheme=scheme, device="cpu")
    plain = time.perf_counter() - t
    gc.collect()
    prof = cProfile.Profile()
    t = time.perf_counter()
    prof.enable()
    ws.refine(ws.Mesh(V, np.full(len(F), F.shape[1]), F.reshape(-1)), level, scheme=scheme, device="cpu")
    prof.disable()
    print(f"ws.refine of {name} ({scheme}) level {level}: {plain:.2f} s unprofiled, "
          f"{time.perf_counter() - t:.2f} s under cProfile; peak RSS {peak_rss_bytes() / MIB:,.0f} MiB\n")
    stats = pstats.Stats(prof).strip_dirs()
    stats.sort_stats("tottime").print_stats(25)
    stats.sort_stats("cumulative").print_stats(30)


# ------------------------------------------------------------------------------------------------ parent
def machine_info(ours_python) -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        ram = None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    code = ("import json, platform, numpy, warp; print(json.dumps({'python': platform.python_version(), "
            "'numpy': numpy.__version__, 'warp': warp.__version__}))")
    try:
        ours = json.loads(subprocess.run([ours_python, "-c", code], capture_output=True, text=True,
                                         timeout=120).stdout.strip().splitlines()[-1])
    except (OSError, IndexError, ValueError, subprocess.TimeoutExpired):
        ours = {}
    return {"cpu": cpu, "cores": cores, "ram_bytes": ram, "os": platform.platform(), "ours": ours}


def library_digest(lib_root: str) -> str:
    """Digest of the measured library's sources (compared at the start and the end of a run)."""
    import hashlib

    digest = hashlib.sha1()
    for folder in ("warp_subdiv", "kernels"):
        for dirpath, dirnames, files in sorted(os.walk(os.path.join(lib_root, folder))):
            dirnames.sort()
            for name in sorted(files):
                if name.endswith(".py"):
                    with open(os.path.join(dirpath, name), "rb") as fh:
                        digest.update(name.encode() + fh.read())
    return digest.hexdigest()[:10]


def _git_state() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "warp_subdiv", "kernels"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
        return f"git {sha}" + (" + uncommitted changes in warp_subdiv/ or kernels/" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "not a git checkout"


def _fmt_s(s):
    if s is None:
        return "–"
    return f"{s * 1e3:.1f} ms" if s < 1 else f"{s:.2f} s"


def _spread(times):
    return f"{100 * (max(times) / min(times) - 1):.0f}%" if times and len(times) > 1 else "–"


def _ratio(x):
    if x is None:
        return "–"
    return f"**{x:.1f}x**" if x >= 10 else f"{x:.2f}x"


def osd_paths(osd: dict) -> dict:
    """End-to-end seconds of OpenSubdiv's paths, from the best time of each phase, and peak RSS after them."""
    topo = osd["topology_s"]
    rss = osd.get("peak_rss_bytes_after", {})
    out = {"topology": {"s": topo, "rss": rss.get("topology")},
           "table_free": {"s": topo + osd["interpolate_s"], "rss": rss.get("interpolate"),
                          "eval_s": osd["interpolate_s"]}}
    pl = osd["per_level_stencils"]
    out["per_level"] = {"s": topo + pl["build_s"] + pl["eval_s"], "rss": rss.get("per_level_stencils"),
                        "build_s": pl["build_s"], "eval_s": pl["eval_s"], "table_bytes": pl["table_bytes"]}
    fz = osd["factorized_stencils"]
    if not fz.get("skipped"):
        out["factorized"] = {"s": topo + fz["build_s"] + fz["eval_s"], "rss": rss.get("factorized_stencils"),
                             "build_s": fz["build_s"], "eval_s": fz["eval_s"], "table_bytes": fz["table_bytes"]}
    else:
        out["factorized"] = {"skipped": f"skipped: estimated build memory {fz['estimated_build_bytes'] / 2**30:.1f} "
                                        f"GiB > budget {fz['budget_bytes'] / 2**30:.1f} GiB"}
    return out


def e2e_table(mesh, scheme, levels, results) -> str:
    head = ["tool", "level", "output verts", "e2e (best)", "first", "reps, spread", "e2e CPU", "core",
            "peak RSS MiB (Δ)",
            "Mverts/s", "peer / ours", "Δ mean‖p‖"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---", "---:"] + ["---:"] * (len(head) - 2)) + "|"]
    for L in levels:
        ours = results.get(("warp-subdiv", mesh, L))
        base = ours["e2e_s"] if ours and "e2e_s" in ours else None
        ref = ours.get("mean_norm") if ours else None
        for tool in ["warp-subdiv"] + list(PEERS) + ["opensubdiv"]:
            r = results.get((tool, mesh, L))
            if tool != "warp-subdiv" and tool != "opensubdiv" and scheme not in PEERS[tool]["schemes"]:
                continue
            if r is None:
                continue
            if "failed" in r:
                lines.append(f"| {tool} | {L} | – | {r['failed']} | | | | | | | | |")
                continue
            if tool == "opensubdiv":
                if "skipped" in r:
                    lines.append(f"| OpenSubdiv | {L} | – | {r['skipped']} | | | | | | | | |")
                    continue
                o, paths = r["osd"], osd_paths(r["osd"])
                for key, label in OSD_PATHS:
                    p = paths[key]
                    if "skipped" in p:
                        lines.append(f"| {label} | {L} | {o['refined_vertices']:,} | {p['skipped']} | | | | | | | | |")
                        continue
                    lines.append("| " + " | ".join([
                        label, str(L), f"{o['refined_vertices']:,}", _fmt_s(p["s"]), "–",
                        f"{o['reps']} per phase", "–",
                        _fmt_s(p["s"] - paths["topology"]["s"]) + " after topology",
                        f"{p['rss'] / MIB:,.0f}" if p.get("rss") else "–",
                        f"{o['refined_vertices'] / p['s'] / 1e6:.1f}",
                        _ratio(p["s"] / base) if base else "–", "–"]) + " |")
                continue
            dmean = f"{abs(r['mean_norm'] - ref) / ref:.1e}" if ref and tool != "warp-subdiv" else "–"
            label = "warp-subdiv ws.refine" if tool == "warp-subdiv" else f"{tool}"
            peak = r.get("peak_rss_e2e", r["peak_rss"])
            lines.append("| " + " | ".join([
                label, str(L), f"{r['num_vertices']:,}", _fmt_s(r["e2e_s"]), _fmt_s(r["e2e_all"][0]),
                f"{len(r['e2e_all'])}, {_spread(r['e2e_all'])}", _fmt_s(r["phases"]["cpu_s"]),
                _fmt_s(r["phases"]["core_s"]),
                f"{peak / MIB:,.0f} ({(peak - r['baseline_peak_rss']) / MIB:,.0f})",
                f"{r['num_vertices'] / r['e2e_s'] / 1e6:.2f}",
                "1 (ours)" if tool == "warp-subdiv" else (_ratio(r["e2e_s"] / base) if base else "–"), dmean,
            ]) + " |")
            if tool == "warp-subdiv" and "build_s" in r:
                lines.append("| " + " | ".join([
                    "warp-subdiv Refiner build", str(L), f"{r['num_vertices']:,}", _fmt_s(r["build_s"]),
                    _fmt_s(r["build_all"][0]),
                    f"{len(r['build_all'])}, {_spread(r['build_all'])}", "", "", "",
                    f"{r['num_vertices'] / r['build_s'] / 1e6:.2f}", "", ""]) + " |")
                lines.append("| " + " | ".join([
                    "warp-subdiv Refiner.evaluate", str(L), f"{r['num_vertices']:,}", _fmt_s(r["eval_s"]),
                    _fmt_s(r["first_eval_s"]),
                    f"{len(r['eval_all'])}, {_spread(r['eval_all'])}", "", "",
                    f"{r['peak_rss'] / MIB:,.0f} ({(r['peak_rss'] - r['baseline_peak_rss']) / MIB:,.0f})",
                    f"{r['num_vertices'] / r['eval_s'] / 1e6:.1f}", "", ""]) + " |")
    return "\n".join(lines)


def eval_floor(level_vertices, bandwidth):
    """Seconds to read every level's parent points once and write its own once (float32 xyz)."""
    nbytes = sum(12 * (a + b) for a, b in zip(level_vertices[:-1], level_vertices[1:]))
    return nbytes, nbytes / bandwidth


def eval_table(rows, results, bandwidth) -> str:
    head = ["mesh", "level", "output verts", "ours evaluate", "ours evaluate_device", "OSD CpuEvaluator per-level",
            "OSD table-free", "OSD factorised", "ours evaluate / OSD per-level", "traffic floor",
            "evaluate / floor", "evaluate_device / floor"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for mesh, L in rows:
        r = results.get(("warp-subdiv", mesh, L))
        o = results.get(("opensubdiv", mesh, L))
        if not r or "eval_s" not in r:
            continue
        paths = osd_paths(o["osd"]) if o and "osd" in o else None
        nbytes, floor = eval_floor(r["level_vertices"], bandwidth)
        pl = paths["per_level"]["eval_s"] if paths else None
        fz = paths["factorized"].get("eval_s") if paths else None
        lines.append("| " + " | ".join([
            mesh, str(L), f"{r['num_vertices']:,}", _fmt_s(r["eval_s"]), _fmt_s(r["eval_device_s"]),
            _fmt_s(pl), _fmt_s(paths["table_free"]["eval_s"]) if paths else "–", _fmt_s(fz),
            f"{r['eval_s'] / pl:.2f}x" if pl else "–",
            f"{_fmt_s(floor)} ({nbytes / MIB:,.0f} MiB)", f"{r['eval_s'] / floor:.1f}x",
            f"{r['eval_device_s'] / floor:.1f}x"]) + " |")
    return "\n".join(lines)


def targets_table(cfg, results, bandwidth) -> str:
    """The targets (BENCHMARKS.md, "Peers"), checked on this run's numbers."""
    lines = ["| target | mesh, level | measured | met? |", "|---|---|---|---|"]

    def row(target, where, text, ok):
        lines.append(f"| {target} | {where} | {text} | {'yes' if ok else '**no**'} |")

    for mesh, levels in cfg:
        scheme = MESHES[mesh][1]
        for L in levels:
            if L not in (4, 5):
                continue
            r = results.get(("warp-subdiv", mesh, L))
            if not r or "e2e_s" not in r:
                continue
            peers = [(results[(t, mesh, L)]["e2e_s"], t) for t in PEERS
                     if scheme in PEERS[t]["schemes"] and "e2e_s" in results.get((t, mesh, L), {})]
            where = f"{mesh} ({scheme}) L{L}"
            if peers:
                best, tool = min(peers)
                row("e2e >= 10x faster than the fastest Python peer", where,
                    f"{tool} {_fmt_s(best)} / ours {_fmt_s(r['e2e_s'])} = {best / r['e2e_s']:.2f}x",
                    best / r["e2e_s"] >= 10)
            o = results.get(("opensubdiv", mesh, L))
            if o and "osd" in o:
                paths = osd_paths(o["osd"])
                pl, tf = paths["per_level"], paths["table_free"]
                row("e2e no slower than OSD topology + per-level stencils + eval", where,
                    f"OSD {_fmt_s(pl['s'])} / ours {_fmt_s(r['e2e_s'])} = {pl['s'] / r['e2e_s']:.2f}x",
                    r["e2e_s"] <= pl["s"])
                row("e2e within 1.5x of OSD table-free", where,
                    f"ours {_fmt_s(r['e2e_s'])} / OSD {_fmt_s(tf['s'])} = {r['e2e_s'] / tf['s']:.2f}x",
                    r["e2e_s"] <= 1.5 * tf["s"])
                if "eval_s" in r:
                    row("Refiner.evaluate no slower than OSD CpuEvaluator (per-level)", where,
                        f"ours {_fmt_s(r['eval_s'])} / OSD {_fmt_s(pl['eval_s'])} = {r['eval_s'] / pl['eval_s']:.2f}x",
                        r["eval_s"] <= pl["eval_s"])
            if "eval_s" in r and bandwidth:
                _, floor = eval_floor(r["level_vertices"], bandwidth)
                row("Refiner.evaluate within 2x of the memory-traffic floor", where,
                    f"{_fmt_s(r['eval_s'])} / {_fmt_s(floor)} = {r['eval_s'] / floor:.1f}x", r["eval_s"] <= 2 * floor)
    if len(lines) == 2:
        lines.append("| (no level 4 or 5 in this run) | | | |")
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="levels 1-2 (cube 1), small bandwidth test, no "
                   "level-6 stress run; peers that are not installed are left out (CI smoke test)")
    p.add_argument("--ours-python", default=sys.executable, help="interpreter with numpy + warp-lang "
                   "(default: this one); the checkout is put on its PYTHONPATH")
    p.add_argument("--peers-python", default=os.environ.get("WS_PEERS_PYTHON", sys.executable),
                   help="interpreter with the Python peers (default: $WS_PEERS_PYTHON, else this one)")
    p.add_argument("--tools", default="all", help="comma-separated subset of warp-subdiv,opensubdiv,"
                   + ",".join(PEERS))
    p.add_argument("--loop-levels", default="4-6", help="Loop levels on icosphere_5120tri (default 4-6)")
    p.add_argument("--cc-levels", default="4-5", help="Catmull-Clark levels on torus_100x50_5000quad (default 4-5)")
    p.add_argument("--cube-levels", default="4-5", help="Catmull-Clark levels on cube64_noisy, warp-subdiv and "
                   "OpenSubdiv only (default 4-5)")
    p.add_argument("--stress-level", type=int, default=6, help="Catmull-Clark level of cube64_noisy tried for "
                   "warp-subdiv end to end only (default 6; 0: none)")
    p.add_argument("--reps", type=int, default=3, help="repetitions per configuration, best taken (default 3)")
    p.add_argument("--rep-budget", type=float, default=150.0, help="stop repeating a configuration once its "
                   "repetitions took this many seconds (default 150)")
    p.add_argument("--frames", type=int, default=5, help="evaluate calls timed after the first (default 5)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per configuration (default 900)")
    p.add_argument("--stress-timeout", type=float, default=1800.0, help="seconds for the stress run (default 1800)")
    p.add_argument("--mem-limit-gib", type=float, default=None,
                   help="kill a configuration whose process tree is above this (default: 90%% of MemAvailable)")
    p.add_argument("--osd-budget-mb", type=float, default=6144, help="OpenSubdiv factorised tables are skipped "
                   "above this estimated build memory (default 6144)")
    p.add_argument("--bw-mib", type=float, default=1024, help="array size of the bandwidth test (default 1024)")
    p.add_argument("--commit", metavar="REV", help="measure warp_subdiv/ and kernels/ of this git commit (exported "
                   "with git archive to a temporary folder), not the working tree, which may change during the run")
    p.add_argument("--json", help="also write every measurement to this JSON file")
    p.add_argument("--report", metavar="JSON", help="print the report of an earlier run from its --json file")
    p.add_argument("--profile", metavar="SCHEME:MESH:LEVEL", help="cProfile one ws.refine (in --ours-python) "
                   "and exit")
    # internal
    p.add_argument("--worker", choices=["ours", "osd", "peer", "probe", "bandwidth", "profile"],
                   help=argparse.SUPPRESS)
    p.add_argument("--tool", help=argparse.SUPPRESS)
    p.add_argument("--mesh", help=argparse.SUPPRESS)
    p.add_argument("--level", type=int, help=argparse.SUPPRESS)
    p.add_argument("--e2e-only", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--lib-root", default=ROOT, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)

    if args.worker:
        if args.worker == "profile":
            profile_ours(args.profile)
            return 0
        fn = {"ours": ours_worker, "osd": osd_worker, "peer": peer_worker, "probe": lambda a: probe_worker(),
              "bandwidth": bandwidth_worker}[args.worker]
        print(MARK + json.dumps(fn(args)), flush=True)
        return 0
    if args.report:
        with open(args.report, encoding="utf-8") as fh:
            render(json.load(fh))
        return 0
    commit = None
    if args.commit:
        args.lib_root, commit = export_commit(args.commit, "wspeers_lib_")
    try:
        if args.profile:
            env = dict(os.environ)
            env["PYTHONPATH"] = args.lib_root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
            if commit:
                print(f"library: git {commit[:7]}, exported snapshot", flush=True)
            return subprocess.run([args.ours_python, os.path.abspath(__file__), "--worker", "profile", "--profile",
                                   args.profile], env=env).returncode
        return run_benchmark(p, args, commit)
    finally:
        if commit:
            import shutil

            shutil.rmtree(args.lib_root, ignore_errors=True)


def run_benchmark(p, args, commit=None) -> int:
    me = os.path.abspath(__file__)
    if args.quick:
        loop_levels, cc_levels, cube_levels, stress = [1, 2], [1, 2], [1], 0
        args.bw_mib = min(args.bw_mib, 64)
        args.frames = min(args.frames, 3)
        args.reps = min(args.reps, 2)
    else:
        loop_levels, cc_levels = parse_levels(args.loop_levels), parse_levels(args.cc_levels)
        cube_levels, stress = parse_levels(args.cube_levels), args.stress_level
    tools = ["warp-subdiv", "opensubdiv"] + list(PEERS)
    if args.tools != "all":
        chosen = [t.strip() for t in args.tools.split(",") if t.strip()]
        bad = [t for t in chosen if t not in tools]
        if bad:
            p.error(f"unknown tools {bad}; choose from {', '.join(tools)}")
        tools = [t for t in tools if t in chosen]
    avail = mem_available_bytes()
    mem_limit = int(args.mem_limit_gib * 2**30) if args.mem_limit_gib else (int(0.9 * avail) if avail else None)
    ours_env = {"PYTHONPATH": args.lib_root + (os.pathsep + os.environ["PYTHONPATH"]
                                               if os.environ.get("PYTHONPATH") else "")}
    common = ["--reps", str(args.reps), "--rep-budget", str(args.rep_budget), "--timeout", str(args.timeout),
              "--lib-root", args.lib_root]

    started = time.perf_counter()
    load0 = os.getloadavg()
    info = machine_info(args.ours_python)
    cmdline = "python bench/bench_peers.py" + "".join(" " + shlex.quote(a) for a in args.argv)
    lib = (f"git {commit[:7]}, exported snapshot of that commit" if commit else _git_state()) + \
        f" (sources {library_digest(args.lib_root)})"
    print(f"bench_peers: {cmdline}; measuring warp-subdiv {lib}", file=sys.stderr, flush=True)

    probe, why = run_child([args.peers_python, me, "--worker", "probe"], 300, None, MARK)
    if probe is None:
        probe = {"peers": {}, "error": f"peers interpreter {args.peers_python} did not answer: {why}"}
    probe["executable"] = args.peers_python
    peer_ok = {t: probe["peers"].get(t, {}).get("available", False) for t in PEERS}
    osd_note = "not requested"
    if "opensubdiv" in tools:
        sys.path.insert(0, ROOT)
        try:
            from peers import osd_peer

            osd_note = (f"OpenSubdiv {osd_peer.version()} (peers/osd_peer.py, C++ single-threaded, "
                        f"g++ -O2)") if osd_peer.available() else "OpenSubdiv peer unavailable (skipped)"
            if not osd_peer.available():
                tools.remove("opensubdiv")
        except Exception as exc:  # noqa: BLE001
            osd_note = f"OpenSubdiv peer unavailable: {exc}"
            tools.remove("opensubdiv")

    bw_runs = []
    bw, why = run_child([args.ours_python, me, "--worker", "bandwidth", "--bw-mib", str(args.bw_mib)], 300,
                        None, MARK)
    if bw:
        bw_runs.append(bw)

    results, notes, crashed = {}, [], False
    cfg = [("icosphere_5120tri", loop_levels), ("torus_100x50_5000quad", cc_levels), ("cube64_noisy", cube_levels)]
    for mesh, levels in cfg:
        scheme = MESHES[mesh][1]
        mesh_tools = [t for t in tools if t in ("warp-subdiv", "opensubdiv")
                      or (mesh != "cube64_noisy" and scheme in PEERS[t]["schemes"])]
        stopped = {}
        for L in levels:
            for tool in mesh_tools:
                if tool in PEERS and not peer_ok[tool]:
                    if not args.quick:
                        results[(tool, mesh, L)] = {"failed": "not installed"}
                    continue
                if tool in stopped:
                    results[(tool, mesh, L)] = {"failed": f"not run ({stopped[tool]} at a lower level)"}
                    continue
                if tool == "warp-subdiv":
                    cmd, env = [args.ours_python, me, "--worker", "ours", "--frames", str(args.frames)], ours_env
                elif tool == "opensubdiv":
                    cmd, env = [args.ours_python, me, "--worker", "osd", "--osd-budget-mb",
                                str(args.osd_budget_mb)], ours_env
                else:
                    cmd, env = [args.peers_python, me, "--worker", "peer", "--tool", tool], None
                cmd += ["--mesh", mesh, "--level", str(L)] + common
                res, why = run_child(cmd, args.timeout, mem_limit, MARK, env)
                if res is None:
                    short = "out of memory" if why.startswith("killed") else (
                        "timeout" if why.startswith("timed out") else "crashed")
                    stopped[tool] = short
                    results[(tool, mesh, L)] = {"failed": why}
                    notes.append(f"{tool} on {mesh} level {L}: {why}")
                    crashed = crashed or (tool == "warp-subdiv" and short == "crashed")
                    print(f"  {tool} {mesh} L{L}: {why}", file=sys.stderr, flush=True)
                    continue
                results[(tool, mesh, L)] = res
                if "e2e_s" in res:
                    print(f"  {tool} {mesh} L{L}: {res['num_vertices']:,} verts, e2e {res['e2e_s']:.3f} s "
                          f"({res['subprocess_wall_s']:.0f} s in subprocess)", file=sys.stderr, flush=True)
                elif "osd" in res:
                    print(f"  {tool} {mesh} L{L}: topology {res['osd']['topology_s']:.3f} s "
                          f"({res['subprocess_wall_s']:.0f} s in subprocess)", file=sys.stderr, flush=True)
                else:
                    print(f"  {tool} {mesh} L{L}: {res}", file=sys.stderr, flush=True)

    stress_res = None
    if stress and "warp-subdiv" in tools:
        cmd = [args.ours_python, me, "--worker", "ours", "--e2e-only", "--mesh", "cube64_noisy", "--level",
               str(stress), "--reps", "1", "--rep-budget", "0", "--timeout", str(args.stress_timeout),
               "--lib-root", args.lib_root]
        res, why = run_child(cmd, args.stress_timeout, mem_limit, MARK, ours_env)
        stress_res = res if res is not None else {"failed": why}
        print(f"  stress cube64_noisy L{stress}: {stress_res.get('failed') or stress_res['e2e_s']}",
              file=sys.stderr, flush=True)

    bw2, _ = run_child([args.ours_python, me, "--worker", "bandwidth", "--bw-mib", str(args.bw_mib)], 300,
                       None, MARK)
    if bw2:
        bw_runs.append(bw2)
    total = time.perf_counter() - started
    load1 = os.getloadavg()
    lib_end = (f"git {commit[:7]}, exported snapshot of that commit" if commit else _git_state()) + \
        f" (sources {library_digest(args.lib_root)})"
    if lib_end != lib:
        notes.append(f"the library changed during this run (start: {lib}; end: {lib_end}): rerun with --commit")
    data = {"command": cmdline, "library": lib, "machine": info, "ours_python": args.ours_python, "peers": probe,
            "osd": osd_note, "bandwidth": bw_runs, "cfg": cfg, "stress_level": stress, "reps": args.reps,
            "rep_budget": args.rep_budget, "timeout": args.timeout, "mem_limit": mem_limit,
            "results": [dict(v, key=list(k)) for k, v in results.items()], "stress": stress_res,
            "notes": notes, "total_s": total, "loadavg_start": load0, "loadavg_end": load1}
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1)
    render(data)
    return 1 if crashed else 0


def render(data: dict) -> None:
    """Print the Markdown report of one run (also ``--report FILE`` with the run's JSON)."""
    info, o, probe = data["machine"], data["machine"].get("ours", {}), data["peers"]
    results = {tuple(r["key"]): r for r in data["results"]}
    cfg = [(m, list(lv)) for m, lv in data["cfg"]]
    stress, stress_res, bw_runs = data["stress_level"], data["stress"], data["bandwidth"]
    print(f"# warp-subdiv against its peers\n\ncommand: `{data['command']}`\n")
    ram = f"{info['ram_bytes'] / 2**30:.1f} GiB" if info["ram_bytes"] else "?"
    print(f"* machine: {info['cpu']}, {info['cores']} cores, {ram} RAM; {info['os']}")
    print(f"* warp-subdiv: {data['library']}; Python {o.get('python')}, numpy {o.get('numpy')}, warp "
          f"{o.get('warp')} ({data['ours_python']}); Warp device cpu, float32, rules piecewise-smooth")
    peer_ok = {t: probe["peers"].get(t, {}).get("available", False) for t in PEERS}
    vers = "; ".join(
        f"{t} " + (f"({', '.join(f'{d} {v}' for d, v in probe['peers'][t]['versions'].items() if v)})"
                   if peer_ok[t] else f"not available ({probe['peers'][t].get('error', 'not installed')})")
        for t in PEERS if t in probe["peers"])
    print(f"* Python peers: Python {probe.get('python')}, numpy {probe.get('numpy')} ({probe.get('executable')}); "
          f"{vers}" + (f" {probe['error']}" if probe.get("error") else ""))
    print(f"* C++ peer: {data['osd']}")
    if data.get("mem_limit"):
        print(f"* guards: {data['timeout']:.0f} s and {data['mem_limit'] / 2**30:.1f} GiB resident (process tree) "
              f"per configuration; best of {data['reps']} repetitions (fewer once they took "
              f"{data['rep_budget']:.0f} s)")
    bandwidth = max((b["bandwidth"] for b in bw_runs), default=None)
    if bandwidth:
        print(f"* memory bandwidth (np.copyto of {bw_runs[0]['bytes'] / MIB:,.0f} MiB float32, (read + write) / "
              f"best of 3, at the start / end of the run): "
              + " / ".join(f"{b['bandwidth'] / 1e9:.2f} GB/s" for b in bw_runs) + "; the floor uses the higher")
    for mesh, levels in cfg:
        if not levels:
            continue
        scheme = MESHES[mesh][1]
        who = "warp-subdiv and OpenSubdiv only" if mesh == "cube64_noisy" else "all peers"
        print(f"\n## {scheme}: {mesh} ({who})\n")
        print(e2e_table(mesh, scheme, levels, results))
    print("\n## Evaluation only: Refiner.evaluate against OpenSubdiv's CPU evaluator and the memory-traffic floor\n")
    print(eval_table([(m, L) for m, lv in cfg for L in lv], results, bandwidth or float("nan")))
    if stress:
        print(f"\n## Stress: warp-subdiv ws.refine, Catmull-Clark cube64_noisy level {stress}\n")
        if stress_res and "e2e_s" in stress_res:
            r = stress_res
            print(f"completed: {r['num_vertices']:,} vertices, {r['num_faces']:,} faces in {r['e2e_s']:.1f} s "
                  f"({r['phases']['cpu_s']:.1f} s CPU); peak RSS {r['peak_rss'] / 2**30:.2f} GiB = "
                  f"{r['peak_rss'] / r['num_vertices']:.0f} B per output vertex "
                  f"({(r['peak_rss'] - r['baseline_peak_rss']) / r['num_vertices']:.0f} B over the baseline after "
                  f"imports)")
        else:
            print(f"did not complete: {stress_res['failed'] if stress_res else 'not run'}")
    print("\n## Targets on this run\n")
    print(targets_table(cfg, results, bandwidth))
    print("\nColumns: e2e = numpy arrays in, refined numpy points + faces out (best of the repetitions; "
          "OpenSubdiv: sum of its phases' best times, face list not read back); first = the first repetition "
          "in the fresh subprocess; e2e CPU = the lowest CPU time (process_time) of the subprocess over the "
          "repetitions; core = the subdivision call alone (warp-subdiv: ws.refine without building ws.Mesh; "
          "OpenSubdiv: the path after its topology refinement); peak RSS = VmHWM of the configuration's own "
          "subprocess at its end (OpenSubdiv: ru_maxrss of the C++ process after that path's phase, which "
          "includes earlier phases' buffers), Δ = minus its VmHWM after imports and mesh load "
          "(warp-subdiv's Refiner.evaluate row: the whole subprocess, Refiner build + evaluations included); "
          "peer / ours = peer e2e / warp-subdiv e2e (> 1: warp-subdiv faster); Δ mean‖p‖ = relative "
          "difference of the mean distance of the output points from the origin against warp-subdiv's (a "
          "check that both computed the same surface).")
    for n in data["notes"]:
        print(f"\n* {n}")
    l0, l1 = data["loadavg_start"], data["loadavg_end"]
    print(f"\nTotal wall time {data['total_s']:.0f} s; 1-minute load average {l0[0]:.2f} at the start, {l1[0]:.2f} "
          f"at the end on {info['cores']} cores (other jobs on the machine slow the timings).")


if __name__ == "__main__":
    sys.exit(main())
