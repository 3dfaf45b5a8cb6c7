"""The ``warp-subdiv`` command line.

``warp-subdiv refine IN.obj -o OUT.obj --levels N`` refines a mesh (OBJ with OpenSubdiv ``t`` tags and
``.creases``/``.corners`` side files) and writes the result. Exit codes: 0 success, 2 usage or input errors
(one line on stderr, no traceback).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from .errors import SubdivInputError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="warp-subdiv", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("refine", help="refine a mesh file and write the refined mesh")
    r.add_argument("input", help="input mesh (.obj)")
    r.add_argument("-o", "--output", required=True, help="output mesh (.obj)")
    r.add_argument("--levels", type=int, required=True, help="number of refinement levels (>= 0)")
    r.add_argument("--scheme", default="auto", choices=["auto", "catmull-clark", "loop"],
                   help="auto: Loop for all-triangle meshes, else Catmull-Clark")
    r.add_argument("--rules", default="piecewise-smooth", choices=["piecewise-smooth", "opensubdiv"])
    r.add_argument("--boundary", default=None, choices=["edge-and-corner", "edge-only", "none"],
                   help="boundary interpolation (default: the file's tag, else edge-and-corner)")
    r.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    r.add_argument("--precision", default="float32", choices=["float32", "float64"])
    r.add_argument("--quiet", action="store_true", help="print nothing on success")
    return p


def _refine(args) -> int:
    import warp as wp

    wp.config.log_level = 30  # warnings and errors only: no start-up banner, no module load lines
    from .objio import read_obj, write_obj
    from .refiner import Refiner

    if not args.input.lower().endswith(".obj"):
        raise SubdivInputError(f"{args.input}: only .obj input is supported so far")
    if not os.path.isfile(args.input):
        raise SubdivInputError(f"{args.input}: no such file")
    start = time.perf_counter()
    data = read_obj(args.input)
    mesh = data.mesh
    scheme = args.scheme
    if scheme == "auto":
        scheme = "loop" if mesh.is_all(3) else "catmull-clark"
    boundary = args.boundary or data.options.get("boundary", "edge-and-corner")
    refiner = Refiner(mesh, args.levels, scheme=scheme, rules=args.rules, boundary=boundary,
                      device=args.device, precision=args.precision)
    refined = refiner.refine()
    out_dir = os.path.dirname(os.path.abspath(args.output))
    os.makedirs(out_dir, exist_ok=True)
    write_obj(args.output, refined.points, refined.face_vertex_counts, refined.face_vertex_indices)
    if not args.quiet:
        elapsed = time.perf_counter() - start
        print(f"{args.input}: {scheme}, {args.rules} rules, {args.levels} levels on {refiner.device}")
        print(f"  faces {mesh.num_faces} -> {refined.num_faces}, vertices {mesh.num_vertices} -> "
              f"{refined.num_vertices}, {elapsed:.2f} s; wrote {args.output}")
    return 0


def main(argv=None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "refine":
            return _refine(args)
    except (SubdivInputError, NotImplementedError, ValueError, OSError) as exc:
        print(f"warp-subdiv: error: {exc}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    sys.exit(main())
