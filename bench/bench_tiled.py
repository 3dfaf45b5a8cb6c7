"""Tiled refinement under a memory limit against the in-core refinement: peak resident memory and time, each in a
fresh process, in one run.

    python bench/bench_tiled.py                                  # cube64_noisy level 5, tiled under 1G
    python bench/bench_tiled.py --levels 6 --max-memory 3G       # BENCHMARKS.md, "Beyond memory"
    python bench/bench_tiled.py --levels 7 --max-memory 8G --no-in-core --obj /tmp/cube_L7.obj
    python bench/bench_tiled.py --levels 7 --max-memory 8G --no-in-core --cli-output /tmp/L7/cube.usdc

``--cli-output PATH`` runs the command line instead (``warp-subdiv refine MESH -o PATH --levels L --max-memory M``,
in the worker process): the whole user path, reading the OBJ, tiling and writing PATH (an OBJ file, or a USD
layer with one payload layer per tile), and reports the bytes written beside the time and peak.

The in-core worker runs ``refine(mesh, levels)``; the tiled worker iterates ``refine_tiled(mesh, levels,
max_memory=...)`` and drops each tile after summing its points (or streams the tiles into ``--obj``). Each
reports its peak resident memory (VmHWM, the whole process: Python, Warp's runtime, the control mesh), its
resident memory before the call (after the mesh is read and Warp's kernels are loaded) and its wall time; a
worker over ``--kill-above`` is killed and reported as such. ``max_memory`` is what the refinement may add to
the process beside Warp's runtime, as the memory guard's model (warp_subdiv.runtime.estimate) has it.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchutil import ROOT, proc_status, quiet_warp, run_child

MARK = "TILED_RESULT "
MESH = os.path.join("/work/shared/meshes/bench", "cube64_noisy.obj")


def worker(args) -> None:
    sys.path.insert(0, ROOT)
    quiet_warp()
    import numpy as np
    import warp_subdiv as ws
    from warp_subdiv.io.obj import read_obj, write_obj_tiles

    mesh = read_obj(args.mesh).mesh
    ws.refine(ws.Mesh(mesh.points[:4], [4], [0, 1, 2, 3]), 1, device="cpu")  # load the kernels
    baseline = proc_status().get("VmRSS", 0)
    start = time.perf_counter()
    if args.cli_output:
        from warp_subdiv.cli import main as cli_main

        code = cli_main(["refine", args.mesh, "-o", args.cli_output, "--levels", str(args.levels), "--max-memory",
                         args.max_memory, "--quiet"])
        result = {"exit": code, "tiles": "cli", "faces": len(mesh.face_vertex_counts) * 4 ** args.levels,
                  "bytes_written": _bytes_written(args.cli_output)}
    elif args.worker == "in-core":
        refined = ws.refine(mesh, args.levels, device="cpu", max_memory=None)
        result = {"vertices": len(refined.points), "faces": len(refined.face_vertex_counts), "tiles": 1}
        del refined
    else:
        tiles = ws.refine_tiled(mesh, args.levels, max_memory=args.max_memory, device="cpu")
        if args.obj:
            count = [0]

            def counted():
                for tile in tiles:
                    count[0] += 1
                    yield tile

            vertices, faces = write_obj_tiles(args.obj, counted())
            result = {"vertices": vertices, "faces": faces, "tiles": count[0]}
        else:
            vertices, faces, count, checksum = 0, 0, 0, 0.0
            for tile in tiles:
                count += 1
                vertices += int(np.count_nonzero(~tile.border))
                faces += tile.num_faces
                checksum += float(tile.points[~tile.border].sum(dtype=np.float64))
            result = {"unshared_vertices": vertices, "faces": faces, "tiles": count, "checksum": checksum}
    result["seconds"] = time.perf_counter() - start
    result["peak_rss"] = proc_status().get("VmHWM", 0)
    result["baseline_rss"] = baseline
    print(MARK + json.dumps(result), flush=True)


def _bytes_written(path: str) -> int:
    """The size of ``path`` and, for a tiled USD layer, of the tile layers in its ``<stem>_tiles`` folder."""
    total = os.path.getsize(path)
    if path.lower().endswith(".obj"):
        return total
    folder = os.path.splitext(path)[0] + "_tiles"
    for root, _, files in os.walk(folder):
        total += sum(os.path.getsize(os.path.join(root, f)) for f in files)
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", default=MESH)
    parser.add_argument("--levels", type=int, default=5)
    parser.add_argument("--max-memory", default="1G")
    parser.add_argument("--no-in-core", action="store_true", help="skip the in-core run")
    parser.add_argument("--obj", default=None, help="tiled: stream the tiles into this OBJ file")
    parser.add_argument("--cli-output", default=None,
                        help="tiled: run `warp-subdiv refine MESH -o PATH --max-memory M` writing PATH (OBJ or USD)")
    parser.add_argument("--kill-above", default="20G", help="kill a worker whose process tree is above this")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args)
    from warp_subdiv.runtime.estimate import format_bytes, parse_size

    kill = parse_size(args.kill_above)
    runs = ([] if args.no_in_core else ["in-core"]) + ["tiled"]
    print(f"{os.path.basename(args.mesh)}, level {args.levels}; tiled under --max-memory {args.max_memory}")
    rows = {}
    for name in runs:
        cmd = [sys.executable, os.path.abspath(__file__), "--worker", name, "--mesh", args.mesh, "--levels",
               str(args.levels), "--max-memory", args.max_memory] + (["--obj", args.obj] if args.obj else []) + (
                   ["--cli-output", args.cli_output] if args.cli_output else [])
        result, reason = run_child(cmd, 7200, kill, MARK, {"PYTHONPATH": ROOT})
        if result is None:
            print(f"  {name:8s} failed: {reason}")
            continue
        rows[name] = result
        print(f"  {name:8s} peak RSS {format_bytes(result['peak_rss']):>10s} (before the call "
              f"{format_bytes(result['baseline_rss'])})  {result['seconds']:8.1f} s  "
              f"{result['tiles']} tile(s), {result['faces']:,} faces"
              + (f", {format_bytes(result['bytes_written'])} written" if "bytes_written" in result else ""))
    if len(rows) == 2:
        a, b = rows["in-core"], rows["tiled"]
        print(f"  tiled / in-core: peak {b['peak_rss'] / a['peak_rss']:.2f}x, time {b['seconds'] / a['seconds']:.2f}x")


if __name__ == "__main__":
    main()
