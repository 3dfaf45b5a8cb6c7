"""A real asset's bake against usd-core's read + write floor: the OpenChessSet (or any USD file).

    python bench/bench_chess.py PATH/TO/chess_set.usda [--levels 2] [--reps 3] [--profile N] [--json OUT]
                                [--lib EXPORTED_CHECKOUT]

The asset is not in the repository. Get it from https://github.com/usd-wg/assets (folder
``full_assets/OpenChessSet``; e.g. ``git clone --depth 1 https://github.com/usd-wg/assets``, then pass
``assets/full_assets/OpenChessSet/chess_set.usda``). Its 21 subdivision mesh prims (8 distinct meshes, 165k
control quads) carry indexed UVs with seams, which the synthetic tori of ``bench_bake.py`` barely have.

In one process, rep by rep (so that a change in the machine's load touches every figure alike):

* **read floor**: usd-core opens the input and reads every subdivision mesh's arrays into numpy (points,
  faceVertexCounts, faceVertexIndices, and every primvar's values and indices; meshes inside instances and
  PointInstancer prototypes too), as the bake's reader must. Before it and before each bake, garbage is
  collected, so that neither finds the input's layers still loaded by an earlier run (which skips parsing
  them: a 5x faster open);
* **bake**: ``warp_subdiv.usd.refine_usd(IN, out.usdc, levels)`` end to end, with its phase times
  (``Result.phases``: read, analyse, refine, face-varying, write, waiting; worker threads' time counts to
  their phases, so the phases add up to more than the wall time); and again on one thread
  (``WARP_SUBDIV_THREADS=1``: no workers, every phase on the calling thread);
* **write floor**: usd-core saving a new ``.usdc`` layer with the arrays of the bake's output
  (``bench_bake.write_floor``: every attribute of the output layer, read back into numpy first).

Ratios printed (the targets in brackets): bake / (read floor + write floor) [1.3], face-varying phase /
refine phase (the vertex refinement) [1.5], the bake's read phase / the read floor [2]; each as the median of
the reps' ratios and best against best.

``--profile N``: afterwards, one more bake on one thread (every phase on this thread, so cProfile sees it all)
under cProfile; prints the N functions with the most own time and the N with the most cumulative time (the
phases' entry points: ``plan`` = read, ``make_refiner`` / ``Hierarchy`` = analyse, ``MeshRefinement.positions``
= refine, ``MeshRefinement.face_varying`` = face-varying, ``OutputLayer.commit`` = write). ``--keep DIR``:
write the outputs there (default: a temporary folder, removed). ``--lib DIR``: import ``warp_subdiv`` from DIR
(e.g. ``git archive REV warp_subdiv kernels | tar -x -C DIR``), to compare a commit before and after on the
same machine.
"""
from __future__ import annotations

import argparse
import cProfile
import gc
import io
import json
import os
import pstats
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (ROOT, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

ASSET_HINT = ("the OpenChessSet is at https://github.com/usd-wg/assets, folder full_assets/OpenChessSet "
              "(pass its chess_set.usda)")


def read_floor(path: str) -> dict:
    """usd-core opens ``path`` and reads every subdivision mesh's arrays into numpy; seconds and counts."""
    from pxr import Usd, UsdGeom

    t0 = time.perf_counter()
    stage = Usd.Stage.Open(path)
    meshes = faces = values = 0
    predicate = Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)
    for prim in Usd.PrimRange(stage.GetPseudoRoot(), predicate):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        if mesh.GetSubdivisionSchemeAttr().Get() == "none":
            continue
        points = np.asarray(mesh.GetPointsAttr().Get())
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
        values += points.size + indices.size
        for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
            value = pv.Get()
            if value is not None and hasattr(value, "__len__") and not isinstance(value, str):
                values += np.asarray(value).size
            if pv.IsIndexed():
                values += np.asarray(pv.GetIndices()).size
        meshes += 1
        faces += len(counts)
    return {"seconds": time.perf_counter() - t0, "meshes": meshes, "faces": faces, "values": values}


def released() -> int:
    """Collect garbage so that no stage of an earlier run holds the input's layers open (a stage left in a
    reference cycle keeps them loaded, and a later open then skips parsing them: 0.02 s instead of 0.12 for
    this asset's read floor); the number of layers still loaded."""
    from pxr import Sdf

    gc.collect()
    return len(Sdf.Layer.GetLoadedLayers())


def profile_bake(scene: str, out: str, levels: int, top: int) -> str:
    """One bake on one thread under cProfile; its report (text)."""
    from bench_bake import bake

    prof = cProfile.Profile()
    prof.enable()
    bake(scene, out, levels, "auto", 1)
    prof.disable()
    text = io.StringIO()
    stats = pstats.Stats(prof, stream=text)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)
    return text.getvalue()


def median(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2] if xs else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=ASSET_HINT)
    ap.add_argument("asset", help="the input (the OpenChessSet's chess_set.usda; " + ASSET_HINT + ")")
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--no-one-thread", action="store_true", help="skip the one-thread bake")
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="then profile a one-thread bake")
    ap.add_argument("--keep", help="folder for the outputs (default: a temporary one, removed)")
    ap.add_argument("--lib", help="import warp_subdiv from this folder instead (e.g. an older commit exported "
                                  "with git archive: a before/after comparison on the same machine)")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    if not os.path.exists(args.asset):
        print(f"bench_chess: {args.asset} not found; {ASSET_HINT}", file=sys.stderr)
        return 2
    if args.lib:
        sys.path.insert(0, os.path.abspath(args.lib))
    import warp_subdiv

    print(f"warp_subdiv from {os.path.dirname(os.path.abspath(warp_subdiv.__file__))}")
    from warp_subdiv.runtime.allocator import retain_freed_memory

    retained = retain_freed_memory()  # as the warp-subdiv command does
    import warp as wp

    wp.config.quiet = True
    from bench_bake import bake, layer_arrays, write_floor
    from pxr import Tf

    Tf.Debug.SetDebugSymbolsByName("*", False)
    folder = args.keep or tempfile.mkdtemp(prefix="wschess_")
    os.makedirs(folder, exist_ok=True)
    out = os.path.join(folder, "baked.usdc")
    runs = {"default": None} if args.no_one_thread else {"default": None, "one-thread": 1}
    try:
        bake(args.asset, out, 1)  # warm-up: Warp loads its kernels once per process; usd-core its plugins
        reads, floors, bakes = [], [], {name: [] for name in runs}
        arrays = None
        for _ in range(args.reps):
            released()
            reads.append(read_floor(args.asset))
            for name, threads in runs.items():
                released()
                bakes[name].append(bake(args.asset, out, args.levels, "auto", threads))
            if arrays is None:
                arrays = layer_arrays(out)
            floors.append(write_floor(arrays, os.path.join(folder, "floor.usdc")))
        result = {"asset": args.asset, "levels": args.levels, "reps": args.reps, "read_floor": reads,
                  "write_floor": floors, "bakes": bakes, "cores": os.cpu_count(), "retain_freed_memory": retained}
        report(result)
        result["load_average"] = os.getloadavg()
        print(f"load average at the end: {', '.join(f'{x:.2f}' for x in result['load_average'])} "
              f"({result['cores']} cores)")
        if args.profile:
            text = profile_bake(args.asset, out, args.levels, args.profile)
            print("\n## cProfile of one bake on one thread\n")
            print(text)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump(result, fh, indent=1)
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    return 0


def report(r: dict) -> None:
    reads = [x["seconds"] for x in r["read_floor"]]
    floors = r["write_floor"]
    first = r["read_floor"][0]
    d = r["bakes"]["default"]
    b0 = d[0]
    print(f"{os.path.basename(r['asset'])}: {first['meshes']} subdivision mesh prims, {first['faces']:,} control "
          f"faces read by usd-core; bake level {r['levels']}: {b0['meshes']} meshes refined, "
          f"{b0['faces_out']:,} faces, {b0['vertices_out']:,} vertices, output {b0['bytes'] / 2**20:.1f} MiB")
    names = list(dict.fromkeys(n for runs in r["bakes"].values() for b in runs for n in b["phases"]))
    heads = {"default": "bake (workers)", "one-thread": "bake on one thread"}
    print("\n| seconds (best of reps; phases of the best bake) | "
          + " | ".join(heads[k] for k in r["bakes"]) + " |\n|---|" + "---:|" * len(r["bakes"]))
    best = {k: min(v, key=lambda b: b["seconds"]) for k, v in r["bakes"].items()}
    for name in names:
        print(f"| {name} | " + " | ".join(f"{b['phases'].get(name, 0):.2f}" for b in best.values()) + " |")
    print("| **end to end (wall)** | " + " | ".join(f"**{b['seconds']:.2f}**" for b in best.values()) + " |")
    print(f"\nusd-core read floor {min(reads):.3f} s (runs {', '.join(f'{x:.3f}' for x in reads)}); write floor "
          f"{min(floors):.2f} s (runs {', '.join(f'{x:.2f}' for x in floors)})")
    print("\n| ratio (target) | " + " | ".join(heads[k] for k in r["bakes"]) + " |\n|---|"
          + "---:|" * len(r["bakes"]))

    def ratios(fn):
        cells = []
        for k, runs in r["bakes"].items():
            per_rep = [fn(b, rd, fl) for b, rd, fl in zip(runs, reads, floors)]
            cells.append(f"{median(per_rep):.2f} (best {fn(best[k], min(reads), min(floors)):.2f}; reps "
                         f"{', '.join(f'{x:.2f}' for x in per_rep)})")
        return " | ".join(cells)

    print("| bake / (read + write floor) (1.3) | "
          + ratios(lambda b, rd, fl: b["seconds"] / (rd + fl)) + " |")
    print("| face-varying / refine phase (1.5) | "
          + ratios(lambda b, rd, fl: b["phases"].get("face-varying", 0) / max(b["phases"].get("refine", 0), 1e-9))
          + " |")
    print("| read phase / read floor (2) | "
          + ratios(lambda b, rd, fl: b["phases"].get("read", 0) / rd) + " |")
    print("| write phase / write floor | "
          + ratios(lambda b, rd, fl: b["phases"].get("write", 0) / fl) + " |")


if __name__ == "__main__":
    sys.exit(main())
