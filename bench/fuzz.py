"""Fuzz warp-subdiv with random valid and malformed meshes: every call either succeeds with finite output or
raises SubdivInputError with a message; never another exception, a hang or a crash.

    python bench/fuzz.py --count 10000 [--seed 0] [--workers 2] [--timeout 20] [--paths all] [--json OUT]

Each case (``random_case(seed)``, reproducible from its seed alone) is a small mesh of one of these kinds:
random polygon or triangle soups (repeated vertices, doubled faces, non-manifold edges and vertices,
unused vertices), grids and closed boxes with faces collapsed, doubled, flipped or punched out, and malformed
input (indices out of range or negative, counts that do not add up, faces of fewer than 3 vertices, NaN,
infinite and huge coordinates, wrong shapes and dtypes, empty meshes); about half get random tags (creases
that may be no edge, sharpness that may be negative, NaN or huge, corners, holes (all faces, too), concave
tags, prescribed normals). Each goes through ``Mesh`` and ``refine`` at a level 0-2 with a random scheme, rule
set, boundary mode, crease method and precision; with ``--paths all`` (the default) also
``Refiner.evaluate`` of random data, a face-varying channel with random indices (evaluate and limit),
``limit_points`` / ``limit_normals``, and every 8th case through the USD reader (a layer written with
usd-core's Sdf API, so that malformed values reach warp-subdiv's reader unchanged).

Cases run in worker processes (``--workers``) that read seeds and report one JSON line each; a worker that
dies (a crash) or takes longer than ``--timeout`` seconds on one case (a hang) is recorded against that seed
and replaced. Exit status 0 when every case succeeded or was refused with SubdivInputError, 1 otherwise.
``tests/test_fuzz.py`` runs 2,000 cases of this script in a child process.
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import threading
import time
import traceback
import warnings
from collections import Counter

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SCHEMES = ("catmull-clark", "loop")
RULES = ("opensubdiv", "piecewise-smooth")
BOUNDARIES = ("edge-and-corner", "edge-only", "none")


# ---------------------------------------------------------------------------------------------- meshes
def _soup(rng, tri: bool):
    """A random polygon (or triangle) soup over a few vertices: repeated vertices inside faces, doubled
    faces, non-manifold edges and vertices, unused vertices."""
    nv = int(rng.integers(3, 18))
    nf = int(rng.integers(1, 16))
    sizes = np.full(nf, 3) if tri else rng.integers(3, 7, nf)
    idx = rng.integers(0, nv, int(sizes.sum()))
    pts = rng.standard_normal((nv, 3))
    return pts, sizes, idx


def _distinct_soup(rng, tri: bool):
    """A soup whose faces use distinct vertices (non-manifold, but no repeats inside a face)."""
    nv = int(rng.integers(4, 20))
    nf = int(rng.integers(1, 16))
    faces = [rng.choice(nv, 3 if tri else int(rng.integers(3, min(7, nv + 1))), replace=False)
             for _ in range(nf)]
    return rng.standard_normal((nv, 3)), np.array([len(f) for f in faces]), np.concatenate(faces)


def grid_quads(nx: int, ny: int):
    """A flat nx x ny grid of unit quads: points (z = 0) and quads as vertex lists, row by row.

    Shared with tests/test_osd_differential.py; callers add their own noise."""
    x, y = np.meshgrid(np.arange(nx + 1, dtype=float), np.arange(ny + 1, dtype=float))
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)

    def v(i, j):
        return j * (nx + 1) + i

    return pts, [[v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1)] for j in range(ny) for i in range(nx)]


def box_quads(n: int):
    """The surface of the cube [0, n]^3 cut into n x n unit quads per side, facing outward: integer points and
    quads as vertex lists. Shared with tests/test_osd_differential.py; callers scale and add noise."""
    ids, pts, quads = {}, [], []
    for axis in range(3):
        u, w = [a for a in range(3) if a != axis]
        for side in (0, n):
            for i in range(n):
                for j in range(n):
                    face = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = [0, 0, 0]
                        p[axis], p[u], p[w] = side, i + di, j + dj
                        face.append(ids.setdefault(tuple(p), len(ids)))
                        if len(ids) > len(pts):
                            pts.append(p)
                    # (u, w, axis) is right-handed except for axis 1; the side at 0 faces the other way
                    quads.append(face[::-1] if (side == 0) != (axis == 1) else face)
    return np.array(pts, float), quads


def _grid(rng, tri: bool):
    nx, ny = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    pts, quads = grid_quads(nx, ny)
    pts[:, 2] = 0.3 * rng.standard_normal(len(pts))
    if tri:
        faces = [f for a, b, c, d in quads for f in ([a, b, c], [a, c, d])]
    else:
        faces = quads
    return pts, np.array([len(f) for f in faces]), np.array(faces).reshape(-1)


def _box(rng, tri: bool):
    n = int(rng.integers(1, 3))
    pts, quads = box_quads(n)
    pts = pts / n + 0.05 * rng.standard_normal((len(pts), 3))
    faces = [f for a, b, c, d in quads for f in ([a, b, c], [a, c, d])] if tri else quads
    return pts, np.array([len(f) for f in faces]), np.array(faces).reshape(-1)


def _damage(rng, pts, counts, idx):
    """Collapse, double, flip or drop some faces of a clean mesh; merge some vertices."""
    faces = np.split(idx, np.cumsum(counts)[:-1])
    out = []
    for f in faces:
        r = rng.random()
        if r < 0.1:
            f = f.copy()
            f[int(rng.integers(len(f)))] = f[int(rng.integers(len(f)))]  # a repeated vertex
        elif r < 0.17:
            out.append(f.copy())  # doubled
        elif r < 0.22:
            f = f[::-1].copy()  # flipped
        elif r < 0.25:
            continue  # dropped
        out.append(f)
    if not out:
        out = faces[:1]
    if rng.random() < 0.3:  # merge two vertices everywhere
        a, b = rng.integers(0, len(pts), 2)
        out = [np.where(f == a, b, f) for f in out]
    return pts, np.array([len(f) for f in out]), np.concatenate(out)


def _malform(rng, pts, counts, idx):
    """One kind of malformed input (or a legal oddity) applied to a mesh; returns (pts, counts, idx)."""
    kind = int(rng.integers(12))
    pts, counts, idx = pts.copy(), counts.copy(), idx.copy()
    if kind == 0:
        idx[int(rng.integers(len(idx)))] = len(pts) + int(rng.integers(0, 5))  # out of range
    elif kind == 1:
        idx[int(rng.integers(len(idx)))] = -int(rng.integers(1, 5))  # negative
    elif kind == 2:
        pts[int(rng.integers(len(pts))), int(rng.integers(3))] = rng.choice([np.nan, np.inf, -np.inf])
    elif kind == 3:
        pts = pts * rng.choice([1e15, 1e30, 1e38, 1e200, 1e300])  # huge coordinates
    elif kind == 4:
        pts = pts * rng.choice([1e-30, 1e-300, 0.0])  # tiny or collapsed coordinates
    elif kind == 5:
        counts[int(rng.integers(len(counts)))] = int(rng.choice([2, 1, 0, -1]))  # fewer than 3 (and no match)
    elif kind == 6:
        j = int(rng.integers(len(counts)))  # a 2-gon or 1-gon that keeps the sums right
        take = int(counts[j]) - int(rng.integers(1, 3))
        start = int(np.sum(counts[:j]))
        idx = np.concatenate([idx[:start + take], idx[start + counts[j]:]])
        counts[j] = take
    elif kind == 7:
        counts = counts[:-1] if len(counts) > 1 else counts + 1  # sums do not add up
    elif kind == 8:
        idx = idx.astype(float) + rng.choice([0.0, 0.5])  # float indices (integral or not)
    elif kind == 9:
        pts = pts[:, :2] if rng.random() < 0.5 else pts.reshape(-1)  # wrong shape
    elif kind == 10:
        counts, idx = counts[:0], idx[:0]  # no faces
    else:
        idx = idx.astype(np.int64) + np.int64(2**40)  # far out of range
    return pts, counts, idx


def _tags(rng, pts, counts, idx, nf):
    """Random (possibly bad) tags as Mesh keywords."""
    kw = {}
    nv = len(pts) if np.ndim(pts) == 2 else 1
    n_idx = len(idx)
    if rng.random() < 0.5 and n_idx:
        m = int(rng.integers(1, 6))
        if rng.random() < 0.7:  # pairs of consecutive face vertices: edges (or degenerate pairs)
            h = rng.integers(0, n_idx, m)
            pairs = np.stack([np.asarray(idx)[h], np.asarray(idx)[np.minimum(h + 1, n_idx - 1)]], 1)
        else:
            pairs = rng.integers(-1, nv + 1, (m, 2))
        kw["creases"] = pairs
        kw["crease_sharpness"] = rng.choice([10.0, 1.5, 0.5, 0.0, 3.25, -1.0, np.nan, 1e30], m,
                                            p=[.3, .15, .15, .1, .1, .05, .05, .1])
    if rng.random() < 0.4:
        m = int(rng.integers(1, 5))
        kw["corners"] = rng.integers(-1 if rng.random() < 0.1 else 0, nv + (1 if rng.random() < 0.1 else 0), m)
        kw["corner_sharpness"] = rng.choice([10.0, 2.0, 0.25, np.inf, 0.0], m, p=[.4, .2, .2, .1, .1])
    if rng.random() < 0.2 and nf > 0:
        kw["holes"] = (np.arange(nf) if rng.random() < 0.3 else
                       rng.integers(0, nf + (1 if rng.random() < 0.1 else 0), int(rng.integers(1, 4))))
    if rng.random() < 0.1 and n_idx:
        h = int(rng.integers(0, n_idx))
        kw["concave"] = [[int(np.asarray(idx)[h]), int(np.asarray(idx)[min(h + 1, n_idx - 1)])]]
    if rng.random() < 0.1 and nv:
        v = rng.choice(nv, min(nv, 2), replace=False)
        n = rng.standard_normal((len(v), 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        kw["normals"] = (v, n)
    return kw


def random_case(seed: int) -> dict:
    """Case ``seed``: dict(points, counts, indices, tags (Mesh keywords), options (refine keywords),
    level, kind). Deterministic in the seed."""
    rng = np.random.default_rng(seed)
    scheme = SCHEMES[int(rng.integers(2))]
    tri = scheme == "loop" and rng.random() < 0.8
    r = rng.random()
    if r < 0.3:
        kind = "soup"
        pts, counts, idx = _soup(rng, tri)
    elif r < 0.45:
        kind = "distinct-soup"
        pts, counts, idx = _distinct_soup(rng, tri)
    elif r < 0.7:
        kind = "damaged"
        pts, counts, idx = (_grid if rng.random() < 0.5 else _box)(rng, tri)
        pts, counts, idx = _damage(rng, pts, counts, idx)
    else:
        kind = "malformed"
        base = [_soup, _grid, _box][int(rng.integers(3))]
        pts, counts, idx = _malform(rng, *base(rng, tri))
    tags = _tags(rng, pts, counts, idx, len(counts)) if rng.random() < 0.5 else {}
    options = dict(scheme=scheme, rules=RULES[int(rng.integers(2))], boundary=BOUNDARIES[int(rng.integers(3))],
                   crease_method=("uniform", "chaikin")[int(rng.integers(2))],
                   precision=("float32", "float64")[int(rng.random() < 0.3)])
    if options["rules"] == "piecewise-smooth" and rng.random() < 0.2:
        options["flatness"] = float(rng.choice([0.0, 0.5, 1.0, np.nan, 2.0]))
    if scheme == "catmull-clark" and rng.random() < 0.2:
        options["triangle_subdivision"] = "smooth"
    return dict(points=pts, counts=counts, indices=idx, tags=tags, options=options, level=int(rng.integers(3)),
                kind=kind)


# ---------------------------------------------------------------------------------------------- one case
def _finite(*arrays) -> None:
    for a in arrays:
        a = np.asarray(a)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise AssertionError(f"non-finite output ({int(np.sum(~np.isfinite(a)))} values)")


def run_case(seed: int, paths: str = "all") -> dict:
    """Run case ``seed``; returns {"seed", "kind", "outcome": "ok" | "refused" | "error", "message"}.

    "refused": SubdivInputError with a non-empty message; "error": any other exception (with its traceback),
    or a result that is not finite, or a refusal without a message."""
    import warp_subdiv as ws

    case = random_case(seed)
    rng = np.random.default_rng(seed + 10**9)
    result = {"seed": seed, "kind": case["kind"], "outcome": "ok", "message": "", "stage": "mesh"}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = ws.Mesh(case["points"], case["counts"], case["indices"], **case["tags"])
            result["stage"] = "refine"
            refiner = ws.Refiner(mesh, case["level"], device="cpu", **case["options"])
            out = refiner.refine()
            _finite(out.points)
            assert out.face_vertex_counts.sum() == len(out.face_vertex_indices)
            assert len(out.face_vertex_indices) == 0 or (out.face_vertex_indices.min() >= 0 and
                                                         out.face_vertex_indices.max() < len(out.points))
            result["stage"] = "other paths"
            if paths == "all":
                data = rng.standard_normal((mesh.num_vertices, int(rng.integers(1, 5))))
                if rng.random() < 0.1:
                    data[int(rng.integers(len(data)))] = np.nan  # must be refused
                _finite(refiner.evaluate(data))
                _finite(out.limit_points(), out.limit_normals())
                nc = len(mesh.face_vertex_indices)
                nvals = int(rng.integers(1, nc + 1))
                fv_idx = rng.integers(0, nvals, nc)
                if rng.random() < 0.1:
                    fv_idx[int(rng.integers(nc))] = nvals + 3  # out of range: must be refused
                fv_vals = rng.standard_normal((nvals, 2))
                mode = ("none", "corners-only", "corners-plus1", "corners-plus2", "boundaries",
                        "all")[int(rng.integers(6))]
                vals, idx = refiner.evaluate_face_varying(fv_vals, fv_idx, mode=mode)
                _finite(vals)
                assert len(idx) == len(out.face_vertex_indices)
                _finite(refiner.limit_face_varying(fv_vals, fv_idx, mode=mode)[0])
                if seed % 8 == 0:
                    _usd_path(case)
    except ws.SubdivInputError as exc:
        result["outcome"] = "refused"
        result["message"] = str(exc)
        if not str(exc).strip():
            result["outcome"] = "error"
            result["message"] = "SubdivInputError without a message"
    except Exception:  # noqa: BLE001 -- any other exception is what the fuzzer looks for
        result["outcome"] = "error"
        result["message"] = traceback.format_exc(limit=-6)
    return result


def _usd_path(case) -> None:
    """The case as a USD layer (written with Sdf, values unchecked) through warp_subdiv's USD reader and
    refiner (the bake's own path for one mesh)."""
    try:
        from pxr import Sdf, Usd, Vt
    except ImportError:
        return
    from warp_subdiv.io import usd_read

    layer = Sdf.Layer.CreateAnonymous(".usda")
    prim = Sdf.CreatePrimInLayer(layer, "/M")
    prim.specifier = Sdf.SpecifierDef
    prim.typeName = "Mesh"

    def put(name, type_name, value):
        attr = Sdf.AttributeSpec(prim, name, type_name)
        try:
            attr.default = value
        except Exception:  # noqa: BLE001 -- a value Sdf cannot hold is simply not written
            pass

    pts = np.asarray(case["points"], dtype=float)
    if pts.ndim == 2 and pts.shape[1] == 3:
        put("points", Sdf.ValueTypeNames.Point3fArray, Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    counts = np.asarray(case["counts"])
    idx = np.asarray(case["indices"])
    if counts.dtype.kind in "iu" and np.all(np.abs(counts) < 2**31):
        put("faceVertexCounts", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    if idx.dtype.kind in "iu" and np.all(np.abs(idx) < 2**31):
        put("faceVertexIndices", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(idx.astype(np.int32)))
    tags = case["tags"]
    if "creases" in tags:
        pairs = np.asarray(tags["creases"]).astype(np.int32)
        put("creaseIndices", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(pairs.reshape(-1)))
        put("creaseLengths", Sdf.ValueTypeNames.IntArray, Vt.IntArray([2] * len(pairs)))
        put("creaseSharpnesses", Sdf.ValueTypeNames.FloatArray,
            Vt.FloatArray.FromNumpy(np.asarray(tags["crease_sharpness"], dtype=np.float32)))
    if "corners" in tags:
        put("cornerIndices", Sdf.ValueTypeNames.IntArray,
            Vt.IntArray.FromNumpy(np.asarray(tags["corners"]).astype(np.int32)))
        put("cornerSharpnesses", Sdf.ValueTypeNames.FloatArray,
            Vt.FloatArray.FromNumpy(np.asarray(tags["corner_sharpness"], dtype=np.float32)))
    if "holes" in tags:
        put("holeIndices", Sdf.ValueTypeNames.IntArray,
            Vt.IntArray.FromNumpy(np.asarray(tags["holes"]).astype(np.int32)))
    put("subdivisionScheme", Sdf.ValueTypeNames.Token,
        {"catmull-clark": "catmullClark", "loop": "loop"}[case["options"]["scheme"]])
    stage = Usd.Stage.Open(layer)
    sp = usd_read.read_mesh(stage.GetPrimAtPath("/M"))
    if sp is None:
        return
    import warp_subdiv as ws
    mesh = sp.mesh if hasattr(sp, "mesh") else None
    if isinstance(mesh, ws.Mesh):
        _finite(ws.refine(mesh, 1, device="cpu", scheme=case["options"]["scheme"]).points)


# ---------------------------------------------------------------------------------------------- workers
def _worker(paths: str) -> None:
    """Read seeds from stdin, one per line; write one JSON result per line."""
    sys.path.insert(0, ROOT)
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = 30
    import warp_subdiv  # noqa: F401 -- imported before the first seed, so that no case pays for it

    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        seed = int(line)
        print(json.dumps(run_case(seed, paths)), flush=True)


class _Worker:
    def __init__(self, paths: str):
        env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker", "--paths", paths],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, env=env, cwd=ROOT)
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)

    def ask(self, seed: int, timeout: float):
        """The result of ``seed``: a dict, "crash" or "hang"."""
        try:
            self.proc.stdin.write(f"{seed}\n")
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            return "crash"
        try:
            line = self.lines.get(timeout=timeout)
        except queue.Empty:
            return "hang"
        return "crash" if line is None else json.loads(line)

    def wait_ready(self, timeout: float = 120) -> bool:
        try:
            line = self.lines.get(timeout=timeout)
        except queue.Empty:
            return False
        return line is not None

    def close(self):
        try:
            self.proc.kill()  # this worker only (its own pid)
        except OSError:
            pass
        self.proc.wait()


def fuzz(seeds, workers: int = 2, timeout: float = 20.0, paths: str = "all", log=None) -> list:
    """Run every seed; returns the result dicts (outcome "crash" / "hang" where a worker died or stalled)."""
    todo: queue.Queue = queue.Queue()
    for s in seeds:
        todo.put(s)
    results, lock = [], threading.Lock()

    def loop():
        w = _Worker(paths)
        w.wait_ready()
        while True:
            try:
                seed = todo.get_nowait()
            except queue.Empty:
                break
            res = w.ask(seed, timeout)
            if not isinstance(res, dict):
                kind = random_case(seed)["kind"]
                res = {"seed": seed, "kind": kind, "outcome": res, "message": f"worker {res} on seed {seed}"}
                w.close()
                w = _Worker(paths)
                w.wait_ready()
            with lock:
                results.append(res)
                if log and res["outcome"] not in ("ok", "refused"):
                    log(f"seed {seed}: {res['outcome']}: {res['message'].strip().splitlines()[-1][:200]}")
        w.close()

    threads = [threading.Thread(target=loop) for _ in range(max(1, workers))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sorted(results, key=lambda r: r["seed"])


def summarize(results) -> dict:
    outcomes = Counter(r["outcome"] for r in results)
    by_kind: dict = {}
    for r in results:
        by_kind.setdefault(r["kind"], Counter())[r["outcome"]] += 1
    reasons = Counter()
    for r in results:
        if r["outcome"] == "refused":
            msg = r["message"]
            reasons[_reason(msg)] += 1
    stages = Counter(r.get("stage", "?") for r in results if r["outcome"] == "refused")
    refined = sum(1 for r in results if r["outcome"] == "ok" or r.get("stage") == "other paths")
    return {"cases": len(results), "outcomes": dict(outcomes), "refused_at": dict(stages),
            "refined_by_mesh_and_refine": refined, "by_kind": {k: dict(v) for k, v in by_kind.items()},
            "refusals": dict(reasons.most_common(15)),
            "failures": [r for r in results if r["outcome"] not in ("ok", "refused")]}


def _reason(msg: str) -> str:
    """A refusal message with its numbers blanked, to count refusals by kind."""
    import re

    return re.sub(r"-?\d+(\.\d+)?(e[+-]?\d+)?", "#", msg.splitlines()[0])[:90]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds one case may take")
    ap.add_argument("--paths", choices=("all", "refine"), default="all")
    ap.add_argument("--json", help="write the summary (and every failure) here")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        _worker(args.paths)
        return 0
    t0 = time.perf_counter()
    results = fuzz(range(args.seed, args.seed + args.count), args.workers, args.timeout, args.paths,
                   log=lambda s: print(s, flush=True))
    wall = time.perf_counter() - t0
    summary = summarize(results)
    summary.update(wall_s=round(wall, 1), workers=args.workers, paths=args.paths, first_seed=args.seed)
    n = summary["cases"]
    print(f"{n} cases in {wall:.1f} s ({args.workers} workers, paths={args.paths})")
    print("| outcome | cases | share |\n|---|---:|---:|")
    for k, v in sorted(summary["outcomes"].items()):
        print(f"| {k} | {v} | {100.0 * v / max(n, 1):.1f}% |")
    print(f"\nrefined by Mesh + refine: {summary['refined_by_mesh_and_refine']} "
          f"({100.0 * summary['refined_by_mesh_and_refine'] / max(n, 1):.1f}%); refused at: "
          + ", ".join(f"{k} {v}" for k, v in summary["refused_at"].items()))
    print("\n| kind | ok | refused | other |\n|---|---:|---:|---:|")
    for k, v in sorted(summary["by_kind"].items()):
        other = sum(c for o, c in v.items() if o not in ("ok", "refused"))
        print(f"| {k} | {v.get('ok', 0)} | {v.get('refused', 0)} | {other} |")
    print("\nmost common refusals:")
    for k, v in summary["refusals"].items():
        print(f"  {v:6d}  {k}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=1, default=str)
    return 0 if not summary["failures"] else 1


if __name__ == "__main__":
    sys.exit(main())
