"""The ``warp-subdiv`` command line.

    warp-subdiv refine IN -o OUT --levels N [options]   refine OBJ or USD (.usd/.usda/.usdc) meshes
    warp-subdiv stitch CHUNK... -o OUT                   stitch the layers of `refine --frames A:B` runs
    warp-subdiv info IN [--levels N]                     the subdivision meshes of a file and predicted sizes
    warp-subdiv render IN -o OUT.png [options]           a shaded preview, ray-cast with Warp
    warp-subdiv tessellate IN -o OUT (--edge-length L | --rate N)   tessellate the limit surfaces

Exit codes: 0 success, 2 usage or input errors (one line on stderr, no traceback), 1 internal errors
(one line; WARP_SUBDIV_DEBUG=1 shows the traceback), 130 interrupted. Outputs are written to a temporary file
and renamed, so a failed run leaves no file.

The library's errors name options by their keywords (``max_memory``) and carry the keyword in their
``option`` field; this module, where it reports them, names the command-line flag instead (``--max-memory``).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
import time
import warnings

from .errors import SubdivInputError

PROG = "warp-subdiv"
#: The library's option keywords that the command line sets, and their flags.
FLAGS = {"levels": "--levels", "prims": "--prim", "scheme": "--scheme", "rules": "--rules", "boundary": "--boundary",
         "device": "--device", "precision": "--precision", "frames": "--frames", "max_memory": "--max-memory",
         "threads": "--threads", "workers": "--workers", "scheduler": "--scheduler", "chunk_frames": "--chunk-frames",
         "camera": "--camera", "view": "--view", "size": "--size", "time": "--time", "samples": "--samples",
         "rate": "--rate", "edge_length": "--edge-length", "depth": "--depth", "flatten": "--flatten",
         "purpose": "--purpose", "all_variants": "--all-variants", "vertex_order": "--vertex-order",
         "max_levels": "--max-levels", "pixel_error": "--pixel-error", "resolution": "--resolution",
         "offscreen_level": "--offscreen-level", "lod_variants": "--lod-variants",
         "skinning": "--skinning", "max_influences": "--max-influences"}


class UsageError(SubdivInputError):
    """A bad command line (exit 2)."""


#: A command-line word that begins with a minus sign and a digit or a point is a value, never an option: frame
#: ranges (``-10:-5``, ``-24:``), time codes (``-1e3``) and angles are negative. argparse before Python 3.13
#: takes only plain negative numbers (``-5``, ``-2.5``) for values and any other such word for an unknown
#: option, so ``--frames -10:-5`` failed with "expected one argument"; 3.13 reads them with this same pattern.
#: No option of this command line looks like that, so reading them as values is never ambiguous.
NEGATIVE_VALUE = re.compile(r"-\.?\d")


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line (and exits 2), as every other user error, and takes
    words such as ``-10:-5`` for the values they are (:data:`NEGATIVE_VALUE`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse asks this pattern whether a word beginning with '-' is a value; it has no public setting
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message):  # argparse API
        raise UsageError(f"{message} (see {self.prog} --help)")


def _parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per job, each with its own arguments."""
    p = _Parser(prog=PROG, description="Loop and Catmull-Clark subdivision of OBJ and USD meshes, with the "
                "piecewise-smooth rules of Biermann, Levin and Zorin (2000) or OpenSubdiv's; exit codes: 0 "
                "success, 2 usage or input errors, 1 internal errors.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    _add_refine(sub)
    _add_stitch(sub)
    _add_info(sub)
    _add_render(sub)
    _add_tessellate(sub)
    return p


def _add_refine(sub) -> None:
    """The arguments of ``refine``."""
    cmd = sub.add_parser("refine", help="refine the subdivision meshes of an OBJ or USD file",
                         description="Refine every subdivision mesh of IN (or those at or under --prim) and write OUT. "
                                     "USD output is a layer that sublayers IN and overrides the refined meshes.")
    cmd.add_argument("input", help="input file: .obj, .usd, .usda or .usdc")
    cmd.add_argument("-o", "--output", required=True, help="output file (.obj for OBJ input; .usd/.usda/.usdc)")
    cmd.add_argument("--levels", type=int, required=True,
                     help="number of refinement levels (>= 0); USD: of the meshes without a subdiv:levels of their "
                          "own or on an ancestor (the nearest wins); with --camera, the most any mesh gets")
    cmd.add_argument("--max-levels", type=int, default=None, metavar="N",
                     help="USD: refine no mesh more than N levels, whatever sets its level")
    _add_camera_arguments(
        cmd, camera="USD: a UsdGeom.Camera prim; with --pixel-error each mesh gets the smallest level whose longest "
                     "refined edge projects to at most that many pixels (the worst of --frames)",
        pixel_error="with --camera: the longest refined edge on screen, in pixels (> 0)",
        offscreen_level="with --camera: the level of meshes outside the camera's frustum (default 0)")
    cmd.add_argument("--lod-variants", default=None, metavar="L0,L1,...",
                     help="USD: write every refined mesh at each of these levels, inside the variants level<N> of a "
                          "variant set subdivLOD (the last selected); meshes defined in the input itself (whose "
                          "local opinions a variant cannot beat) get them in a flattened output: --flatten, else "
                          "flattened with a warning")
    cmd.add_argument("--prim", action="append", metavar="PATH",
                     help="refine only the meshes at or under this prim path (repeatable; USD only)")
    cmd.add_argument("--scheme", default="auto", choices=["auto", "catmull-clark", "loop"],
                     help="auto: each USD mesh's subdivisionScheme (OBJ: Loop for all-triangle meshes, else "
                          "Catmull-Clark); otherwise force this scheme on every subdivision mesh")
    cmd.add_argument("--rules", default=None, choices=["piecewise-smooth", "opensubdiv"],
                     help="rule set for every mesh (default: each mesh's subdiv:rules, else piecewise-smooth)")
    cmd.add_argument("--boundary", default=None, choices=["edge-and-corner", "edge-only", "none"],
                     help="boundary interpolation (default: the file's interpolateBoundary / tag)")
    cmd.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: cuda when present)")
    cmd.add_argument("--precision", default="float32", choices=["float32", "float64"])
    cmd.add_argument("--frames", default=None, metavar="A:B",
                     help="refine only the time samples in [A, B] (A:, :B and A work too; USD only)")
    cmd.add_argument("--limit", action="store_true", help="write limit points instead of refined control points")
    cmd.add_argument("--normals", action="store_true", help="write limit normals (vertex interpolation)")
    cmd.add_argument("--max-memory", default=None, metavar="SIZE",
                     help="refuse when the predicted memory is larger (e.g. 512M, 8G; 'none': no limit; "
                          "default: half of the physical memory)")
    cmd.add_argument("--flatten", action="store_true",
                     help="write one self-contained layer (the composed, flattened stage) instead of an "
                          "override layer that sublayers the input")
    cmd.add_argument("--all-variants", action="store_true",
                     help="USD: refine every variant of the variant sets that change a subdivision mesh (nested "
                          "sets too) and write each inside the same variant set and variant (default: the "
                          "selected variants, as composed)")
    cmd.add_argument("--vertex-order", default="auto", choices=["auto", "compact", "opensubdiv"],
                     help="USD: numbering of the refined vertices; the surface is the same. compact: vertices that "
                          "are children of control vertices keep their numbers, the others follow the faces that "
                          "first use them, so that usdc compresses the indices well and writes them much faster; "
                          "opensubdiv: OpenSubdiv's (and warp_subdiv.refine()'s) numbering; auto (default): "
                          "compact for meshes refined with the piecewise-smooth rules, opensubdiv for "
                          "rules=opensubdiv")
    cmd.add_argument("--skinning", default="bake", choices=["bake", "keep", "none"],
                     help="USD meshes bound to a UsdSkel skeleton: bake (default: at every time the pose changes, "
                          "the control points as UsdSkel deforms them, refined, the binding dropped: what a "
                          "renderer draws), keep (the rest pose refined and the binding refined with it, an "
                          "approximation, with a warning) or none (the rest pose refined, the binding dropped)")
    cmd.add_argument("--max-influences", type=int, default=None, metavar="N",
                     help="with --skinning keep: joints per refined vertex (default: the input's elementSize)")
    cmd.add_argument("--semi-sharp-as-sharp", action="store_true",
                     help="make semi-sharp creases and corners (0 < sharpness < 10) infinitely sharp, with a warning "
                          "(default: they are refined as semi-sharp, with OpenSubdiv's semantics)")
    cmd.add_argument("--progress", default="auto", choices=["auto", "on", "off"],
                     help="progress bar on stderr (auto: when stderr is a terminal)")
    cmd.add_argument("--quiet", action="store_true", help="print nothing on success (warnings still go to stderr)")
    cmd.add_argument("--threads", type=int, default=None, metavar="N",
                     help="CPU threads for evaluation (default: the cores this process may use); results do not "
                          "depend on it")
    cmd.add_argument("--workers", type=int, default=None, metavar="N",
                     help="bake on a local Dask cluster of N worker processes (USD; needs the 'distributed' extra)")
    cmd.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="bake on the Dask cluster whose scheduler is at ADDRESS (e.g. tcp://host:8786)")
    cmd.add_argument("--chunk-frames", type=int, default=None, metavar="N",
                     help="with --workers/--scheduler: time samples per frame task of an animated mesh "
                          "(default: about 3 tasks per worker)")
    cmd.add_argument("--fresh", action="store_true",
                     help="USD: refine everything again, ignoring (and removing) the work that a killed run of the "
                          "same bake kept in OUT.resume/ (by default a rerun reuses it)")
    cmd.add_argument("--no-resume", action="store_true",
                     help="USD: keep nothing for a rerun (no OUT.resume/: a killed bake starts over; saves writing "
                          "each refined mesh twice)")


def _add_stitch(sub) -> None:
    """The arguments of ``stitch``."""
    cmd = sub.add_parser("stitch", help="stitch the layers of `refine --frames A:B` runs into one output",
                         description="Assemble chunk layers written by `warp-subdiv refine IN -o CHUNK --frames A:B` "
                                     "runs (same input, levels and options) into OUT: each animated mesh's chunks "
                                     "become USD value clips. Give the ranges shared ends (1:25 25:50) for values "
                                     "between frames to interpolate across chunks.")
    cmd.add_argument("chunks", nargs="+", metavar="CHUNK", help="chunk layers (.usd, .usda, .usdc), any order")
    cmd.add_argument("-o", "--output", required=True, help="output layer (.usd, .usda, .usdc)")
    cmd.add_argument("--flatten", action="store_true", help="write one self-contained layer (clips baked in)")
    cmd.add_argument("--quiet", action="store_true", help="print nothing on success")


def _add_info(sub) -> None:
    """The arguments of ``info``."""
    cmd = sub.add_parser("info", help="list the subdivision meshes of a file with predicted output sizes")
    cmd.add_argument("input", help="input file: .obj, .usd, .usda or .usdc")
    cmd.add_argument("--levels", type=int, default=4,
                     help="predict sizes for levels 1..N (default 4); USD: the level of meshes without a "
                          "subdiv:levels (each mesh's level is shown with where it comes from)")
    cmd.add_argument("--max-levels", type=int, default=None, metavar="N", help="USD: as for refine")
    _add_camera_arguments(cmd, camera="USD: show the levels refine --camera would choose (with --pixel-error)",
                          pixel_error="with --camera: as for refine", resolution="with --camera: as for refine",
                          offscreen_level="with --camera: as for refine")
    cmd.add_argument("--prim", action="append", metavar="PATH", help="only meshes at or under this prim path")


def _add_render(sub) -> None:
    """The arguments of ``render``."""
    cmd = sub.add_parser("render", help="render a shaded preview PNG (Warp ray casting, CPU or CUDA)")
    cmd.add_argument("input", help="a USD file (or .obj)")
    cmd.add_argument("-o", "--output", required=True, help="output .png")
    cmd.add_argument("--prim", action="append", metavar="PATH", help="render only meshes at or under this path")
    cmd.add_argument("--camera", default=None, metavar="PATH",
                     help="a UsdGeom.Camera prim to look through (default: frame the meshes from --view)")
    cmd.add_argument("--view", nargs=2, type=float, default=(-60.0, 30.0), metavar=("AZ", "EL"),
                     help="azimuth and elevation in degrees of the framing camera around the up axis "
                          "(default -60 30)")
    cmd.add_argument("--size", default="800x600", metavar="WxH", help="image size in pixels (default 800x600)")
    cmd.add_argument("--time", default=None,
                     help="time code to render (default: the stage's start time; without one, the first time "
                          "sample of points that have no default value)")
    cmd.add_argument("--levels", type=int, default=None,
                     help="refine subdivision meshes before rendering, as refine does: each USD mesh to its "
                          "subdiv:levels (or its nearest ancestor's), the others this many levels (default: "
                          "as stored)")
    cmd.add_argument("--cage", default=None, metavar="FILE",
                     help="draw the control meshes of this USD file (e.g. the input of a refinement) as lines")
    cmd.add_argument("--samples", type=int, default=2, help="samples per pixel along each axis (default 2)")
    cmd.add_argument("--purpose", default=None, choices=["render", "proxy"],
                     help="USD: draw the meshes of this purpose with those of the default purpose, as a renderer "
                          "does: render (default; what a final frame shows) or proxy (the stand-ins of "
                          "interactive views); guides are never drawn")
    cmd.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: cuda when present)")


_RESOLUTION_HELP = "with --camera: the image size (default: the stage's render settings, else 1920x1080)"


def _add_camera_arguments(cmd, *, camera: str, pixel_error: str, resolution: str = _RESOLUTION_HELP,
                          offscreen_level: str | None = None, camera_group=None) -> None:
    """--camera, --pixel-error, --resolution (and --offscreen-level where ``offscreen_level`` gives its help) with
    each command's own help texts; ``camera_group``: the group --camera belongs to (tessellate: one of the ways
    to choose rates)."""
    (camera_group or cmd).add_argument("--camera", default=None, metavar="PRIM", help=camera)
    cmd.add_argument("--pixel-error", type=float, default=None, metavar="PX", help=pixel_error)
    cmd.add_argument("--resolution", default=None, metavar="WxH", help=resolution)
    if offscreen_level is not None:
        cmd.add_argument("--offscreen-level", type=int, default=None, metavar="N", help=offscreen_level)


def _add_tessellate(sub) -> None:
    """The arguments of ``tessellate``."""
    cmd = sub.add_parser("tessellate", help="tessellate the limit surfaces of an OBJ or USD file (watertight, "
                                            "adaptive by edge length or a rate)",
                         description="Evaluate the limit surface of every subdivision mesh of IN (or those at or under "
                                     "--prim) and write a watertight tessellation to OUT, with the conventions of "
                                     "refine (USD: a layer that sublayers IN and overrides the meshes).")
    cmd.add_argument("input", help="input file: .obj, .usd, .usda or .usdc")
    cmd.add_argument("-o", "--output", required=True, help="output file (.obj for OBJ input; .usd/.usda/.usdc)")
    how = cmd.add_mutually_exclusive_group(required=True)
    how.add_argument("--edge-length", type=float, metavar="L",
                     help="target edge length in object space: each control edge gets ceil(limit length / L) "
                          "segments")
    how.add_argument("--rate", type=int, metavar="N", help="segments per control edge (uniform)")
    _add_camera_arguments(
        cmd, camera_group=how,
        camera="USD: a UsdGeom.Camera prim; with --pixel-error each control edge gets ceil(its limit curve's "
               "projected length / PX) segments (the worst of --frames)",
        pixel_error="with --camera: the longest segment on screen, in pixels (> 0)")
    cmd.add_argument("--prim", action="append", metavar="PATH", help="only meshes at or under this prim path (USD)")
    cmd.add_argument("--scheme", default="auto", choices=["auto", "catmull-clark", "loop"],
                     help="as for refine: auto takes each mesh's subdivisionScheme (OBJ: Loop for all triangles)")
    cmd.add_argument("--rules", default=None, choices=["piecewise-smooth", "opensubdiv"])
    cmd.add_argument("--boundary", default=None, choices=["edge-and-corner", "edge-only", "none"])
    cmd.add_argument("--depth", type=int, default=None,
                     help="levels of local refinement near irregular features before end caps (default 8)")
    cmd.add_argument("--triangles", action="store_true", help="triangles only (default: quads where uniform)")
    cmd.add_argument("--frames", default=None, metavar="A:B",
                     help="as for refine: tessellate the points' time samples in [A, B] (default: all)")
    cmd.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: cuda when present)")
    cmd.add_argument("--max-memory", default=None, metavar="SIZE",
                     help="as for refine (default: half of the physical memory): a mesh whose tessellation would "
                          "not fit is tessellated in tiles that do (OBJ: one OBJ file, or a USD Xform of tile "
                          "meshes; USD: a sibling Xform <name>_tiles of tile meshes, the mesh deactivated)")
    cmd.add_argument("--flatten", action="store_true", help="write one self-contained layer (USD)")
    cmd.add_argument("--all-variants", action="store_true",
                     help="as for refine: tessellate every variant that changes a mesh, inside its variant set (USD)")
    cmd.add_argument("--quiet", action="store_true", help="print nothing on success")


# -- progress and messages -------------------------------------------------------------------------------

class ProgressBar:
    """A one-line progress bar on stderr, redrawn at most ten times a second; cleared when done."""

    def __init__(self, enabled: bool, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.start = time.perf_counter()
        self.last = 0.0
        self.shown = False

    def __call__(self, fraction: float, label: str) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.last < 0.1 and fraction < 1.0:
            return
        self.last = now
        width = shutil.get_terminal_size((80, 20)).columns
        bar = "#" * int(20 * fraction) + "-" * (20 - int(20 * fraction))
        line = f"[{bar}] {100 * fraction:3.0f}% {now - self.start:5.1f}s {label}"
        self.stream.write("\r" + line[: width - 1].ljust(width - 1))
        self.stream.flush()
        self.shown = True

    def clear(self) -> None:
        if self.shown:
            width = shutil.get_terminal_size((80, 20)).columns
            self.stream.write("\r" + " " * (width - 1) + "\r")
            self.stream.flush()
            self.shown = False


def _warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def _quiet_warp():
    import warp as wp

    wp.config.log_level = 30  # warnings and errors only: no start-up banner, no module load lines
    return wp


def _max_memory(text):
    from .runtime.estimate import default_max_memory, parse_size

    if text is None:
        return default_max_memory()
    return parse_size(text)


def _check_device(device) -> None:
    """A Warp device this machine has (None: the default); a usage error otherwise."""
    if device is None:
        return
    wp = _quiet_warp()
    try:
        wp.get_device(device)
    except Exception as exc:  # noqa: BLE001 (Warp raises ValueError or RuntimeError)
        raise UsageError(f"--device {device}: {_one_line(exc)}") from None


def _kind(path: str) -> str | None:
    """"obj" or "usd", the kind of file ``path`` names by its extension; None for any other."""
    from .io.usd_write import USD_EXTENSIONS

    ext = os.path.splitext(path)[1].lower()
    if ext == ".obj":
        return "obj"
    if ext in USD_EXTENSIONS:
        return "usd"
    return None


def _either(names) -> str:
    """``(".a", ".b", ".c")`` -> ``".a, .b or .c"``."""
    return ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0]


def _check_input(path: str) -> str:
    """The kind of the input file ``path`` ("obj" or "usd"); an error when it is of another type or missing."""
    kind = _kind(path)
    if kind is None:
        raise SubdivInputError(f"{path}: only .obj, .usd, .usda and .usdc input is supported")
    if not os.path.exists(path):
        raise SubdivInputError(f"{path}: no such file")
    if os.path.isdir(path):
        raise SubdivInputError(f"{path}: is a folder, not a file")
    return kind


def _check_output(path: str, input_kind: str) -> str:
    """The kind of the output file ``path`` ("obj" or "usd"); a usage error, naming the types an input of
    ``input_kind`` is written as, when its extension is missing or another (OBJ input is written as OBJ or USD,
    USD input as USD only)."""
    from .io.usd_write import USD_EXTENSIONS

    written_as = ((".obj",) if input_kind == "obj" else ()) + tuple(USD_EXTENSIONS)
    ext = os.path.splitext(path)[1].lower()
    if not ext:
        raise UsageError(f"{path}: give the output an extension ({_either(written_as)})")
    if ext not in written_as:
        raise UsageError(f"{path}: cannot write {ext}: {input_kind.upper()} input is written as {_either(written_as)}")
    return _kind(path)


# -- refine --------------------------------------------------------------------------------------------

def _table(rows, header, left=(0, 1, 2)) -> list:
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    fmt = lambda r: "  ".join(str(c).ljust(w) if i in left else str(c).rjust(w)  # noqa: E731
                              for i, (c, w) in enumerate(zip(r, widths)))
    return [fmt(header)] + [fmt(r) for r in rows]


def _summary(source, output, levels, device, reports, seconds, predicted, phases=None) -> None:
    from .runtime.estimate import format_bytes

    mixed = {r.level for r in reports if r.level is not None} - {levels}
    print(f"{source} -> {output}: {levels} levels on {device}" + (" (per mesh: see the level column)" if mixed else ""))
    header = ("prim", "scheme", "rules", "level", "faces in", "faces out", "vertices out", "samples", "time")
    rows = [(r.path, r.scheme, r.rules, "-" if r.level is None else r.level, f"{r.faces_in:,}", f"{r.faces_out:,}",
             f"{r.vertices_out:,}", r.samples,
             f"{r.seconds:.2f} s") for r in reports]
    for line in _table(rows, header):
        print("  " + line)
    fin = sum(r.faces_in for r in reports)
    fout = sum(r.faces_out for r in reports)
    vin = sum(r.vertices_in for r in reports)
    vout = sum(r.vertices_out for r in reports)
    print(f"  total: {len(reports)} mesh{'es' if len(reports) != 1 else ''}, faces {fin} -> {fout}, vertices {vin} -> "
          f"{vout}, {seconds:.2f} s (predicted memory {format_bytes(predicted)}); wrote {output}")
    if phases:  # where the time went (warp_subdiv.runtime.phases)
        overlap = " (worker threads' time included: they overlap the writer)" if "waiting" in phases else ""
        print("  phases: " + ", ".join(f"{name} {sec:.2f} s" for name, sec in phases.items()) + overlap)


def _refine(args) -> int:
    if args.levels < 0:
        raise UsageError(f"--levels must be >= 0, got {args.levels}")
    kind = _check_input(args.input)
    out_kind = _check_output(args.output, kind)
    max_memory = _max_memory(args.max_memory)
    _check_device(args.device)
    counts = (("--threads", args.threads), ("--workers", args.workers), ("--chunk-frames", args.chunk_frames))
    for flag, value in counts:
        if value is not None and value < 1:
            raise UsageError(f"{flag} must be >= 1, got {value}")
    if kind == "obj" and (args.workers or args.scheduler):
        raise UsageError("--workers and --scheduler apply to USD input only")
    from .runtime.threads import set_default_threads

    set_default_threads(args.threads)
    show = args.progress == "on" or (args.progress == "auto" and sys.stderr.isatty())
    progress = ProgressBar(not args.quiet and show)
    try:
        if kind == "obj":
            return _refine_obj(args, out_kind, max_memory, progress)
        return _refine_usd(args, max_memory, progress)
    finally:
        progress.clear()


def _refine_usd(args, max_memory, progress) -> int:
    _quiet_warp()
    from .usd import refine_usd
    from .io.usd_stage import parse_frames

    frames = parse_frames(args.frames)
    run = dict(prims=args.prim, scheme=args.scheme, rules=args.rules, boundary=args.boundary, device=args.device,
               precision=args.precision, frames=frames, limit=args.limit, normals=args.normals,
               max_memory=max_memory, flatten=args.flatten, semi_sharp="sharp" if args.semi_sharp_as_sharp else "keep",
               progress=progress, fresh=args.fresh, resume=not args.no_resume)
    run["vertex_order"] = args.vertex_order  # always passed: every chunk of a distributed bake numbers alike
    levels = dict(max_levels=args.max_levels, camera=args.camera, pixel_error=args.pixel_error,
                  resolution=args.resolution, offscreen_level=args.offscreen_level, lod_variants=args.lod_variants)
    run.update((k, v) for k, v in levels.items() if v is not None)
    run.update(skinning=args.skinning, max_influences=args.max_influences)
    if args.all_variants:
        if args.workers or args.scheduler:
            raise UsageError("--all-variants does not combine with --workers or --scheduler")
        run["all_variants"] = True
    if args.lod_variants is not None and (args.workers or args.scheduler):
        raise UsageError("--lod-variants does not combine with --workers or --scheduler")
    if args.workers or args.scheduler:
        from .usd import bake

        result = bake(args.input, args.output, args.levels, workers=args.workers, scheduler=args.scheduler,
                      chunk_frames=args.chunk_frames, threads=args.threads, **run)
    else:
        result = refine_usd(args.input, args.output, args.levels, **run)
    progress.clear()
    for w in result.warnings:
        _warn(w)
    if not args.quiet:
        _summary(args.input, args.output, args.levels, _device_name(args.device), result.reports, result.seconds,
                 result.predicted_bytes, getattr(result, "phases", None))
        if result.reused or result.reused_samples:  # a killed run's finished work, copied (not refined)
            print(f"resumed: {len(result.reused)} {'tasks' if hasattr(result, 'timings') else 'meshes'} and "
                  f"{sum(result.reused_samples.values())} time samples kept by an earlier run")
    return 0


def _device_name(device) -> str:
    from .evaluator import default_device

    return str(device or default_device())


def _refine_obj(args, out_kind, max_memory, progress) -> int:
    _quiet_warp()
    from .runtime.estimate import MemoryGuardError, check_memory, estimate
    from .io.obj import read_obj, write_obj
    from .usd import make_refiner, options_for

    if args.prim or args.frames:
        raise UsageError("--prim and --frames apply to USD input only")
    if any(v is not None for v in (args.max_levels, args.camera, args.pixel_error, args.resolution,
                                   args.offscreen_level, args.lod_variants)):
        raise UsageError("--max-levels, --camera, --pixel-error, --resolution, --offscreen-level and --lod-variants "
                         "apply to USD input only")
    if args.limit or args.normals or args.flatten or args.all_variants:
        raise UsageError("--limit, --normals, --flatten and --all-variants apply to USD input only")
    start = time.perf_counter()
    data = read_obj(args.input)
    mesh = data.mesh
    options = options_for(data, scheme=args.scheme, rules=args.rules, boundary=args.boundary,
                          precision=args.precision)
    scheme, rules = options.scheme.value, options.rules.value
    # the control mesh is analysed once: the analysis says whether the refiner projects (the memory it
    # predicts), and the refiner of args.levels starts from it
    control = make_refiner(data, 0, options=options, device=args.device)
    est = estimate(args.input, mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges, args.levels, scheme,
                   precision=options.precision.value, projecting=control.projects)
    try:
        check_memory([est], max_memory, args.levels)
    except MemoryGuardError:
        return _refine_obj_tiled(args, data, options, max_memory, start, out_kind)  # it fits in tiles
    progress(0.0, f"{args.input}: {args.levels} levels")
    refiner = make_refiner(data, args.levels, options=options, device=args.device, reuse=(control.hierarchy,))
    progress(0.7, f"{args.input}: points")
    refined = refiner.refine()
    progress(0.9, f"writing {args.output}")
    from .io.usd_write import make_folders, remove_folders, write_mesh_layer

    out_dir = os.path.dirname(os.path.abspath(args.output))
    created = []
    try:
        created = make_folders(out_dir)
        if out_kind == "obj":
            write_obj(args.output, refined.points, refined.face_vertex_counts, refined.face_vertex_indices)
        else:
            write_mesh_layer(os.path.abspath(args.output), os.path.splitext(os.path.basename(args.input))[0],
                             refined.points, refined.face_vertex_counts, refined.face_vertex_indices)
    except OSError as exc:
        remove_folders(created)
        raise SubdivInputError(f"{args.output}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        remove_folders(created)  # a failed run leaves no folder it made
        raise
    progress.clear()
    if not args.quiet:
        print(f"{args.input}: {scheme}, {rules} rules, {args.levels} levels on {refiner.device}")
        print(f"  faces {mesh.num_faces} -> {refined.num_faces}, vertices {mesh.num_vertices} -> "
              f"{refined.num_vertices}, {time.perf_counter() - start:.2f} s; wrote {args.output}")
    return 0


def _refine_obj_tiled(args, data, options, max_memory, start, out_kind) -> int:
    """An OBJ refinement that does not fit ``max_memory`` at once: refined in tiles that each fit
    (:func:`warp_subdiv.refine_tiled`), streamed into one OBJ file or written as one USD layer per tile under an
    Xform (:func:`warp_subdiv.io.usd_write.write_tiles`)."""
    from .io.usd_write import write_tiles
    from .tiled import refine_tiled

    tiles = refine_tiled(data.mesh, args.levels, max_memory=max_memory, options=options, device=args.device,
                         threads=args.threads)
    count, vertices, faces = write_tiles(args.output, tiles, out_kind,
                                         os.path.splitext(os.path.basename(args.input))[0],
                                         header=f"warp-subdiv: level {args.levels} in tiles")
    written = f"{count} tiles" if out_kind == "obj" else \
        f"{count} tiles (one layer each in {os.path.splitext(args.output)[0]}_tiles/)"
    if not args.quiet:
        print(f"{args.input}: {options.scheme.value}, {options.rules.value} rules, {args.levels} levels in {written} "
              "(the whole refinement would not fit --max-memory)")
        print(f"  faces {data.mesh.num_faces} -> {faces}, vertices {data.mesh.num_vertices} -> {vertices}, "
              f"{time.perf_counter() - start:.2f} s; wrote {args.output}")
    return 0


# -- stitch --------------------------------------------------------------------------------------------

def _stitch(args) -> int:
    from .usd import stitch

    result = stitch(args.chunks, args.output, flatten=args.flatten)
    if not args.quiet:
        print(f"{len(args.chunks)} chunk layer{'s' if len(args.chunks) != 1 else ''} -> {args.output}, "
              f"{result.seconds:.2f} s; wrote {args.output}")
    return 0


# -- info ----------------------------------------------------------------------------------------------

def _info(args) -> int:
    from .runtime.estimate import estimate, format_bytes

    kind = _check_input(args.input)
    if args.levels < 0:
        raise UsageError(f"--levels must be >= 0, got {args.levels}")
    if kind == "obj" and any(v is not None for v in (args.max_levels, args.camera, args.pixel_error,
                                                     args.resolution, args.offscreen_level)):
        raise UsageError("--max-levels, --camera, --pixel-error, --resolution and --offscreen-level apply to USD "
                         "input only")
    if kind == "obj":
        _quiet_warp()
        from .io.obj import read_obj
        from .usd import make_refiner, options_for

        data = read_obj(args.input)
        mesh = data.mesh
        options = options_for(data)
        print(f"{args.input}: 1 mesh (OBJ)")
        print(f"{os.path.basename(args.input)}")
        _print_control(mesh, options.scheme.value, options.boundary.value, options.rules.value)
        projecting = make_refiner(data, 0, options=options, device="cpu").projects
        _print_levels(lambda lv: estimate(args.input, mesh.num_vertices, mesh.face_vertex_counts, mesh.num_edges,
                                          lv, options.scheme.value, projecting=projecting), args.levels)
        return 0
    _quiet_warp()
    from pxr import UsdGeom

    from .usd import estimate_prim, make_refiner, plan
    from .usd.skinning import describe_skinning

    # info never refuses a valid file: a skinned mesh that the default bake refuses (inside an instance) is
    # described, with the treatments that apply
    p = plan(args.input, args.levels, prims=args.prim, require_meshes=False, describe_instances=True,
             max_levels=args.max_levels, camera=args.camera, pixel_error=args.pixel_error,
             resolution=args.resolution, offscreen_level=args.offscreen_level)
    stage = p.stage
    times = ""
    if stage.HasAuthoredTimeCodeRange():
        times = f", time codes {stage.GetStartTimeCode():g} to {stage.GetEndTimeCode():g}"
    print(f"{args.input}: {len(p.prims)} subdivision mesh{'es' if len(p.prims) != 1 else ''} (upAxis "
          f"{UsdGeom.GetStageUpAxis(stage)}, metersPerUnit {UsdGeom.GetStageMetersPerUnit(stage):g}{times})")
    uses = p.scene.uses()
    for sp, options, key, analysis, level in zip(p.prims, p.options, p.keys, p.analyses, p.levels):
        print(sp.path)
        if uses.get(key, 1) > 1:
            print(f"  refined once for {uses[key]} meshes (instances of one prototype, or identical inputs)")
        source = p.level_sources.get(sp.path, (level, "levels"))[1]
        print(f"  level: {level} ({_flagged(source, ('levels', 'max_levels'))})")
        _print_control(sp.mesh, sp.scheme, sp.boundary, sp.rules, sp.usd_scheme, sp.orientation)
        print(f"  tags: {_tags_summary(sp)}")
        if sp.point_times:
            times = sp.point_times
            print(f"  time: points have {len(times)} samples ({times[0]:g} to {times[-1]:g})")
        else:
            print("  time: static points")
        for name, times in sp.point_arrays.items():
            print(f"  {name}: " + (f"{len(times)} samples" if times else "static"))
        if sp.primvars:
            print("  primvars: " + ", ".join(
                f"{pv.name.split(':', 1)[1]} ({pv.interpolation} {pv.type_name}{', indexed' if pv.indexed else ''})"
                for pv in sp.primvars))
        for name, reason in sp.dropped:
            print(f"  not refinable: {name} ({reason})")
        skinned = describe_skinning(sp)
        if skinned:
            print(f"  skinned: {skinned}")
        for w in sp.warnings:
            print(f"  note: {w}")
        control = make_refiner(sp, 0, options=options, reuse=(getattr(analysis, "hierarchy", None),))
        _print_levels(lambda lv, sp=sp, control=control: estimate_prim(sp, lv, control=control), args.levels)
    for path, reason in p.left_alone:
        print(f"{path}: left alone ({reason})")
    if any(source != "levels" for _, source in p.level_sources.values()):  # else each is --levels, as said above
        print("levels (each mesh read; instances of one prototype by the first one):")
        for path, (level, source) in p.level_sources.items():
            print(f"  {path}: {level} ({_flagged(source, ('levels', 'max_levels'))})")
    print(f"total predicted memory at {args.levels} levels: {format_bytes(p.predicted_bytes)}")
    return 0


def _print_control(mesh, scheme, boundary, rules, usd_scheme=None, orientation=None) -> None:
    import numpy as np

    sizes = mesh.face_vertex_counts
    kinds = [f"{int(np.count_nonzero(sizes == 3))} triangles", f"{int(np.count_nonzero(sizes == 4))} quads"]
    other = int(np.count_nonzero(sizes > 4))
    if other:
        kinds.append(f"{other} larger polygons")
    head = f"  scheme {usd_scheme} -> {scheme}" if usd_scheme else f"  scheme {scheme}"
    print(f"{head}, rules {rules if scheme != 'bilinear' else '-'}, boundary {boundary}"
          + (f", {orientation}" if orientation else ""))
    print(f"  control: {mesh.num_vertices} points, {mesh.num_faces} faces ({', '.join(kinds)}), {mesh.num_edges} edges")


def _tags_summary(sp) -> str:
    """The tags a USD mesh as read (a SubdivPrim) carries, in one line."""
    m = sp.mesh
    parts = [f"{len(m.creases)} crease edges", f"{len(m.corners)} corners", f"{len(m.concave)} concave",
             f"{len(m.holes)} holes", f"{len(m.normal_vertices)} normals"]
    if sp.flatness is not None:
        parts.append("flatness " + (f"{sp.flatness:g}" if isinstance(sp.flatness, float) else "per point"))
    if sp.normal_strength is not None:
        parts.append(f"normal strength {sp.normal_strength:g}")
    return ", ".join(parts)


def _print_levels(estimate_at, levels: int) -> None:
    """A table of predicted faces, vertices and memory for levels 1..levels."""
    from .runtime.estimate import format_bytes

    rows = []
    for lv in range(1, levels + 1):
        e = estimate_at(lv)
        rows.append((lv, f"{e.final.faces:,}", f"{e.final.vertices:,}", format_bytes(e.working_bytes + e.output_bytes)))
    if rows:
        for line in _table(rows, ("level", "faces", "vertices", "memory"), left=()):
            print("    " + line)


# -- tessellate and render -----------------------------------------------------------------------------

def _tessellate(args) -> int:
    _quiet_warp()
    from .usd.tessellate import tessellate_file

    _check_output(args.output, _check_input(args.input))
    if args.rate is not None and args.rate < 1:
        raise UsageError(f"--rate must be at least 1, got {args.rate}")
    if args.edge_length is not None and not args.edge_length > 0:
        raise UsageError(f"--edge-length must be positive, got {args.edge_length}")
    _check_device(args.device)
    max_memory = _max_memory(args.max_memory)
    result = tessellate_file(args.input, args.output, rate=args.rate, edge_length=args.edge_length, prims=args.prim,
                             scheme=args.scheme, rules=args.rules, boundary=args.boundary, depth=args.depth,
                             quads=not args.triangles, device=args.device, flatten=args.flatten,
                             frames=args.frames, all_variants=args.all_variants, camera=args.camera,
                             pixel_error=args.pixel_error, resolution=args.resolution, max_memory=max_memory)
    for w in result.warnings:
        _warn(w)
    if not args.quiet:
        how = (f"rate {args.rate}" if args.rate is not None else f"edge length {args.edge_length:g}"
               if args.edge_length is not None else f"camera {args.camera}, {args.pixel_error:g} px")
        print(f"{args.input} -> {args.output}: limit surfaces tessellated ({how}) on {_device_name(args.device)}")
        for r in result.reports:
            if r.tiles:
                print(f"  {r.path}: in {r.tiles} tiles (the whole tessellation would not fit --max-memory)")
        header = ("prim", "scheme", "rules", "faces in", "faces out", "vertices out", "time")
        rows = [(r.path, r.scheme, r.rules, f"{r.faces_in:,}", f"{r.faces_out:,}", f"{r.vertices_out:,}",
                 f"{r.seconds:.2f} s") for r in result.reports]
        for line in _table(rows, header):
            print("  " + line)
        print(f"  total: {len(result.reports)} mesh{'es' if len(result.reports) != 1 else ''}, "
              f"{result.seconds:.2f} s; wrote {args.output}")
    return 0


def _render(args) -> int:
    if os.path.splitext(args.output)[1].lower() != ".png":
        raise UsageError(f"{args.output}: the preview is written as .png")
    kind = _check_input(args.input)
    _quiet_warp()
    from .render import check_view, parse_resolution, render_file

    size = parse_resolution(args.size)
    view = check_view(args.view)
    if args.samples < 1 or args.samples > 8:
        raise UsageError(f"--samples must be 1 to 8, got {args.samples}")
    if args.levels is not None and args.levels < 0:
        raise UsageError(f"--levels must be >= 0, got {args.levels}")
    if args.cage is not None:
        _check_input(args.cage)
    if kind == "obj" and args.purpose is not None:
        raise UsageError("--purpose applies to USD input only")
    _check_device(args.device)
    render_file(args.input, args.output, kind=kind, prims=args.prim, camera=args.camera, view=view, size=size,
                time=args.time, levels=args.levels, cage=args.cage, samples=args.samples, device=args.device,
                purpose=args.purpose or "render")
    return 0


# -- main ----------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    try:
        parser = _parser()
        args = parser.parse_args(argv)
        from .runtime.allocator import retain_for_command

        retain_for_command()  # a bake's temporaries reuse freed memory (WARP_SUBDIV_RETAIN_MEMORY=0: not)
        run = {"refine": _refine, "info": _info, "render": _render, "stitch": _stitch,
               "tessellate": _tessellate}[args.command]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = run(args)
        seen = set()
        for w in caught:
            text = str(w.message).splitlines()[0] if str(w.message) else w.category.__name__
            text = _flagged(text, getattr(w.message, "option", None))
            if text not in seen:
                seen.add(text)
                _warn(text)
        return code
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"{PROG}: error: out of memory; lower --levels (or --max-memory, whose prediction was too low)",
              file=sys.stderr)
        return 2
    except SubdivInputError as exc:  # bad input, including the command line's own errors
        print(f"{PROG}: error: {_phrase(exc)}", file=sys.stderr)
        return 2
    except (OSError, NotImplementedError) as exc:  # files that cannot be read or written; a feature not there
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:  # the last line of defence: no traceback for the user
        if _is_usd_error(exc):  # USD could not read the input
            from .io.usd_stage import tf_message

            print(f"{PROG}: error: {tf_message(exc)}", file=sys.stderr)
            return 2
        if os.environ.get("WARP_SUBDIV_DEBUG"):
            raise
        print(f"{PROG}: internal error: {type(exc).__name__}: {_one_line(exc)} (a bug in warp-subdiv; set "
              "WARP_SUBDIV_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        text = f"{exc.filename}: {exc.strerror}"
    return text or type(exc).__name__


def _phrase(exc: SubdivInputError) -> str:
    """The error's message in one line, the option at fault (its ``option`` field) named by its flag."""
    return _flagged(_one_line(exc), exc.option)


def _flagged(text: str, option) -> str:
    """``text`` with the library's keyword ``option`` (or each of a tuple of them, where the command line has
    it) named by its flag."""
    for name in option if isinstance(option, tuple) else (option,):
        flag = FLAGS.get(name) if isinstance(name, str) else None
        if flag:
            text = re.sub(rf"(?<![\w:./-]){re.escape(name)}(?![\w./-])", flag, text)
    return text


def _is_usd_error(exc: BaseException) -> bool:
    return type(exc).__module__.startswith("pxr") and type(exc).__name__ == "ErrorException"


if __name__ == "__main__":
    sys.exit(main())
