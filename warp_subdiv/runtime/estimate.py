"""Predicted sizes of a refinement, before any work: vertex, face and corner counts per level, and bytes.

Counts follow from the control mesh alone (V vertices, F faces, E edges, C face corners):

* Catmull-Clark (and bilinear): V' = V + F + E, F' = C, E' = 2E + C; from level 1 on every face is a quad,
  so C' = 4F'.
* Loop: polygons are first fan-triangulated (F = C - 2F, E = E + C - 3F, C = 3F); then V' = V + E, F' = 4F,
  E' = 2E + 3F, C' = 3F'.

Bytes (what the memory guard compares with ``max_memory``) model the peak resident memory a refinement
adds to the process, phase by phase, from per-vertex costs measured with ``python bench/bench_memory.py``
(BENCHMARKS.md, "Memory estimate"; each configuration in a fresh process, peak RSS over the RSS before the
call). Every cost is per vertex of the last level a phase builds, because every level is 4x the previous
one and the last one dominates:

* the control-mesh analysis (edges, rings, sectors): 175 bytes per control face corner at its peak, 40 of
  which stay while the later levels are built (the analysed level 0 and the first step's tables; the rest of
  the peak is reused by the build); this matters where few levels refine a large control mesh;
* building the refiner (topology of every level, tables, numpy temporaries): 106 bytes per output vertex for
  Catmull-Clark, 115 for Loop; where the piecewise-smooth rules project on every level (flatness at
  extraordinary crease and corner sectors, prescribed normals) the last level is built with its full
  topology: 245 and 310; 55 of these are the second-to-last level's full topology, which for one level is
  the control mesh, counted above;
* after the build the refiner keeps 80 / 110 bytes per output vertex (215 / 310 where it projects); a frame
  adds one float buffer per vertex of every level and data width, and the returned points;
* a face-varying primvar (UVs) is refined by a refiner of its own over the value mesh, built while the
  vertex refiner is alive: 55 bytes per output vertex at the peak (it reuses memory the vertex refiner's
  build released; measured 40 to 110 over repeated runs), plus one kept refiner where there are several
  channels (the previous channel's is dropped once the next one is built);
* limit points and normals (the CLI's ``--limit``, ``--normals``) build full topology and mask tables of the level they
  read: 755 (Catmull-Clark) or 680 (Loop) bytes per vertex of that level; where the refiner projects or its
  edge rules differ next to extraordinary crease vertices that level is one deeper, and a refiner is built
  for it: 860 or 865 bytes per vertex of the deeper level;
* writing a USD layer maps each refined face to its control face (24 bytes a face at the peak of building
  the map) and converts the topology and points to USD arrays (4 bytes a face and a face corner; 40 a vertex:
  refined points, their USD copy, extent and used-vertex temporaries) while the refiner is alive;
* what the written layer holds until it is saved: face counts and indices once, and per written time sample
  the points (and extent), velocities, accelerations, normals and primvars.

The working set is freed after each mesh, the layer's data is not: the total is the sum of every mesh's
output plus the largest working set, plus 64 MiB for Warp's runtime and kernels.
"""
from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import SubdivInputError

#: Bytes per control face corner of the control-mesh analysis (edges, rings, sectors): at its own peak, and
#: what stays (level 0 and the first step's tables) while the later levels are built.
CONTROL_PEAK = 175
CONTROL_KEPT = 40
#: Part of BUILD_PEAK and KEPT that is the second-to-last level's full topology: with one level, that level is
#: the control mesh, counted by CONTROL_KEPT already.
PENULTIMATE = 55
#: Bytes per output vertex at the peak of building a refiner, without and with projections (see above).
BUILD_PEAK = {"catmull-clark": (106, 245), "loop": (115, 310)}
#: Bytes per output vertex a built refiner keeps (index tables, masks, the last level's topology).
KEPT = {"catmull-clark": (80, 215), "loop": (110, 310)}
#: Bytes per output vertex that refining one face-varying channel adds at the peak of a USD run (its value
#: mesh refiner reuses memory the vertex refiner's build released; measured 40-110 over runs).
FACE_VARYING = 55
#: Bytes per vertex of the level whose limit masks are built (its full topology, masks, temporaries): on the
#: last level, and one level deeper (which also builds a refiner for that level).
LIMIT_PEAK = {"catmull-clark": (755, 860), "loop": (680, 865)}
#: Warp's runtime and loaded kernel modules (measured: about 30 to 60 MiB on the CPU).
RUNTIME_BYTES = 64 * 2**20
#: The refiner's tables are int32: no level may hold this many face corners.
MAX_CORNERS = 2**31 - 1
#: The largest count a 32-bit offset, index or array dimension holds (the CSR offsets of stencil and limit
#: tables, the elements of a level buffer, a launch's rows).
INT32_MAX = 2**31 - 1
#: Device memory left free by the guard on CUDA: the context, loaded modules and the allocator's slack.
DEVICE_RESERVE = 256 * 2**20


@dataclass
class LevelCounts:
    level: int
    vertices: int
    faces: int
    edges: int
    corners: int


def level_counts(num_vertices: int, face_sizes, num_edges: int, levels: int, scheme: str) -> list[LevelCounts]:
    """Predicted counts for levels 0..levels (level 0 is the control mesh as the refiner sees it).

    ``scheme`` is "catmull-clark", "bilinear" or "loop". Counts are Python ints (they may exceed int64 for
    absurd requests and must still compare correctly).
    """
    sizes = np.asarray(face_sizes, dtype=np.int64)
    V, F, E, C = int(num_vertices), int(len(sizes)), int(num_edges), int(sizes.sum())
    if scheme == "loop" and not np.all(sizes == 3):
        F, E, C = C - 2 * F, E + C - 3 * F, 3 * (C - 2 * F)
    out = [LevelCounts(0, V, F, E, C)]
    for lvl in range(1, levels + 1):
        if scheme == "loop":
            V, F, E = V + E, 4 * F, 2 * E + 3 * F
            C = 3 * F
        else:
            V, F, E = V + F + E, C, 2 * E + C
            C = 4 * F
        out.append(LevelCounts(lvl, V, F, E, C))
    return out


@dataclass
class Estimate:
    """Predicted output of one mesh: the last level's counts and the bytes it needs, item by item."""

    path: str
    counts: list
    working_bytes: int  # freed after the mesh is done
    output_bytes: int  # kept in the output layer until it is saved
    items: dict = field(default_factory=dict)

    @property
    def final(self) -> LevelCounts:
        return self.counts[-1]


def estimate(
    path: str,
    num_vertices: int,
    face_sizes,
    num_edges: int,
    levels: int,
    scheme: str,
    *,
    precision: str = "float32",
    samples: int = 1,
    vertex_width: int = 0,
    face_varying_width: int = 0,
    face_varying_channels: int = 0,
    uniform_width: int = 0,
    extra_point_arrays: int = 0,
    projecting: bool = False,
    limit: bool = False,
    limit_deeper: bool = False,
    layer: bool = False,
) -> Estimate:
    """Bytes needed to refine one mesh ``levels`` times and hold ``samples`` written time samples.

    ``vertex_width``: floats per vertex of the refined vertex and varying primvars (all of them together);
    ``face_varying_width`` the same per face corner, ``uniform_width`` per face; ``face_varying_channels``:
    face-varying primvars, each refined by a value-mesh refiner built while the vertex refiner is alive (the
    previous channel's is dropped once the next one is built). ``extra_point_arrays``:
    further 3-vectors per vertex and sample (velocities, accelerations, normals). ``projecting``: the refiner
    builds flatness or normal-control tables on every level (``Refiner.projects``). ``limit``: limit points
    or normals are computed; ``limit_deeper``: their masks are read one level deeper
    (``Refiner.limit_reads_deeper``). ``layer``: the result is written to a USD layer (``refine_usd``), which
    maps every refined face to its control face and converts the topology to USD arrays while the refiner
    is alive.
    """
    key = "loop" if scheme == "loop" else "catmull-clark"
    counts = level_counts(num_vertices, face_sizes, num_edges, levels + (1 if limit and limit_deeper else 0), key)
    limit_level = counts[-1]
    counts = counts[: levels + 1]
    last = counts[-1]
    real = 8 if precision == "float64" else 4
    all_vertices = sum(c.vertices for c in counts)
    control = CONTROL_KEPT * counts[0].corners
    penultimate = PENULTIMATE if levels == 1 else 0
    build = (BUILD_PEAK[key][int(bool(projecting))] - penultimate) * last.vertices
    kept = (KEPT[key][int(bool(projecting))] - penultimate) * last.vertices
    frame = real * (3 + vertex_width) * (all_vertices + last.vertices)
    items = {
        "control mesh analysis": control,
        "refiner build": build,
        "refiner kept": kept,
        "frame buffers": frame,
        "face-varying refiners": (FACE_VARYING + (KEPT[key][0] if face_varying_channels > 1 else 0))
        * last.vertices if face_varying_channels else 0,
        "limit masks": LIMIT_PEAK[key][int(bool(limit_deeper))] * limit_level.vertices if limit else 0,
        "layer conversion": 24 * last.faces + 4 * (last.faces + last.corners) + 40 * last.vertices if layer else 0,
        "faces": 4 * (last.faces + last.corners),
        "points": samples * last.vertices * 12 * (1 + extra_point_arrays),
        "primvars": samples * 4 * (last.vertices * vertex_width + last.corners * face_varying_width
                                   + last.faces * uniform_width),
    }
    evaluation = kept + frame + items["face-varying refiners"]
    working = max(CONTROL_PEAK * counts[0].corners, control + max(build, evaluation)) + items["limit masks"] \
        + items["layer conversion"]
    output = items["faces"] + items["points"] + items["primvars"]
    return Estimate(path, counts, working, output, items)


def total_bytes(estimates, concurrent: int = 1) -> int:
    """Peak bytes of refining these meshes into one layer, ``concurrent`` of them at a time (1: one after the
    other; the USD bake's workers refine a few ahead of the writer): every output, the largest ``concurrent``
    working sets, and the runtime."""
    estimates = list(estimates)
    if not estimates:
        return 0
    working = sorted((e.working_bytes for e in estimates), reverse=True)[:max(1, int(concurrent))]
    return sum(e.output_bytes for e in estimates) + sum(working) + RUNTIME_BYTES


class MemoryGuardError(SubdivInputError):
    """The predicted memory is above the limit (``option`` "max_memory", ``value`` the predicted bytes), or the
    output would not fit 32-bit indices (``option`` "levels")."""


def check_index_range(estimates, levels: int) -> None:
    """Refuse outputs whose face corners would not fit the refiner's 32-bit index tables."""
    for e in estimates:
        if e.final.corners > MAX_CORNERS:
            raise MemoryGuardError(
                f"{e.path}: level {levels} has {e.final.faces:,} faces ({e.final.corners:,} face corners), more "
                "than 32-bit tables can index; lower levels", option="levels", value=levels,
            )


def check_memory(estimates, max_memory, levels: int) -> None:
    """The memory guard: refuse, before any work, when the prediction is above ``max_memory`` (bytes or a size
    string, see :func:`memory_limit`), and outputs beyond 32-bit indices."""
    max_memory = memory_limit(max_memory)
    estimates = list(estimates)
    check_index_range(estimates, levels)
    need = total_bytes(estimates)
    if max_memory is not None and need > max_memory:
        biggest = max(estimates, key=lambda e: e.output_bytes + e.working_bytes)
        raise MemoryGuardError(
            f"refining {len(estimates)} mesh(es) to level {levels} would need about {format_bytes(need)} "
            f"({biggest.path}: {biggest.final.faces:,} faces, {biggest.final.vertices:,} vertices), more than "
            f"max_memory {format_bytes(max_memory)}; refine fewer levels"
            + (" or fewer meshes" if len(estimates) > 1 else "") + ", or raise max_memory; or refine in tiles "
            "that fit (warp_subdiv.refine_tiled; `warp-subdiv refine` and the USD bake do so by themselves)",
            option="max_memory", value=need,
        )


def check_int32(count: int, what: str, *, option: str = "levels") -> None:
    """Refuse, with :class:`MemoryGuardError` (``value`` the count), a count that 32-bit offsets, indices or
    array sizes cannot hold; ``what`` says what it counts. Called with the computed size before the table or
    buffer is allocated."""
    if int(count) > INT32_MAX:
        raise MemoryGuardError(f"{what}: {int(count):,}, more than 32-bit offsets and indices can hold "
                               f"({INT32_MAX:,}); refine fewer levels", option=option, value=int(count))


def check_buffer_elements(elements: int, what: str) -> None:
    """A level buffer of ``elements`` values (rows x data width) must fit a 32-bit size."""
    check_int32(elements, f"{what} needs level buffers of up to this many values", option="data")


def limit_entries(num_vertices: int, num_corners: int, scheme: str) -> int:
    """Entries of a level's limit position table, at least (the tangent tables are as large): a vertex's mask
    covers it and its ring, 2 vertices per face corner around it for Catmull-Clark (edge neighbour and face
    diagonal), 1 for Loop. Boundary rings add one more per boundary vertex."""
    per_corner = 1 if scheme == "loop" else 2
    return int(num_vertices) + per_corner * int(num_corners)


def check_limit_tables(num_vertices: int, num_corners: int, scheme: str, level: int) -> None:
    """Refuse limit masks of a level whose tables' 32-bit CSR offsets would wrap, before they are built."""
    check_int32(limit_entries(num_vertices, num_corners, scheme),
                f"the limit masks of level {level} ({int(num_vertices):,} vertices) need table entries")


def device_bytes(counts, scheme: str, precision: str = "float32", width: int = 3, limit: bool = False,
                 tagged_edges: int = 0) -> dict:
    """Device memory of a refiner's evaluation, item by item (bytes): the step tables as
    :class:`~warp_subdiv.tables.RegularTables` stores them (a step over a level that is not all quads or
    triangles as full stencils, about 10 entries per child vertex), with explicit rows for the boundary
    (boundary edges B = 2E - C of a manifold mesh, doubling every level: a crease vertex row of 3 entries
    and a crease edge row of 2 per boundary edge) and twice that per ``tagged_edges`` (interior crease edges:
    both sides' neighbours), 10% more, the level buffers for data of ``width``, and with ``limit`` the limit
    masks of the last level and their outputs. ``counts``: :func:`level_counts` of the refinement."""
    real = 8 if precision == "float64" else 4
    loop = scheme == "loop"
    tables = 0
    boundary = max(0, 2 * counts[0].edges - counts[0].corners) + 2 * int(tagged_edges)
    for parent, child in zip(counts[:-1], counts[1:]):
        V, F, E, C = parent.vertices, parent.faces, parent.edges, parent.corners
        uniform = C == (3 if loop else 4) * F
        explicit = boundary * (2 * 8 + 5 * (4 + real)) + V + E  # rows, offsets, entries; the row masks
        boundary *= 2
        if not uniform:
            tables += 10 * (4 + real) * child.vertices + 4 * (child.vertices + 1)
        elif loop:
            tables += 16 * E + 4 * (V + 1) + 4 * C + explicit
        else:
            tables += 4 * C + 8 * E + 4 * (V + 1) + 4 * C + explicit
    items = {"step tables": int(1.1 * tables),
             "level buffers": real * width * sum(c.vertices for c in counts)}
    if limit:
        last = counts[-1]
        entries = limit_entries(last.vertices, last.corners, scheme)
        items["limit masks"] = 3 * (entries * (4 + real) + 4 * (last.vertices + 1))
        items["limit outputs"] = real * last.vertices * (width + 3) + 2 * 3 * real * last.vertices
    return items


def device_free_memory(device) -> tuple[int, int] | None:
    """(free, total) bytes of a CUDA device (Warp's ``Device.free_memory`` / ``total_memory``), or None for the
    CPU (the host guard covers it)."""
    if not getattr(device, "is_cuda", False):
        return None
    return int(device.free_memory), int(device.total_memory)


def check_device_memory(need: int, device, what: str) -> None:
    """On CUDA, refuse (:class:`MemoryGuardError`, ``option`` "device") before allocating when ``need`` bytes
    and :data:`DEVICE_RESERVE` are more than the device has free; on the CPU nothing (the host memory guard
    applies). ``device``: a Warp device, or any object with ``is_cuda``, ``free_memory``, ``total_memory``."""
    memory = device_free_memory(device)
    if memory is None:
        return
    free, total = memory
    if int(need) + DEVICE_RESERVE > free:
        name = getattr(device, "alias", str(device))
        raise MemoryGuardError(
            f"{what} would need about {format_bytes(need)} of memory on {name} ({format_bytes(free)} free of "
            f"{format_bytes(total)}); refine fewer levels or use device 'cpu'",
            option="device", value=int(need))


def physical_memory() -> int | None:
    """Bytes of physical memory, or None where the platform does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def default_max_memory() -> int:
    """Half of the physical memory (8 GiB where it cannot be found out)."""
    phys = physical_memory()
    return phys // 2 if phys else 8 * 2**30


_UNITS = {"": 1, "b": 1, "k": 2**10, "kb": 2**10, "kib": 2**10, "m": 2**20, "mb": 2**20, "mib": 2**20,
          "g": 2**30, "gb": 2**30, "gib": 2**30, "t": 2**40, "tb": 2**40, "tib": 2**40}


def parse_size(text: str) -> int | None:
    """'512M', '8G', '1.5GiB', '1000000' -> bytes (binary units); 'none' or '0' -> None (no limit)."""
    s = str(text).strip().lower()
    if s in ("none", "off", "0", "unlimited"):
        return None
    num = s.rstrip("abcdefghijklmnopqrstuvwxyz")
    unit = s[len(num):].strip()
    try:
        value = float(num)
    except ValueError:
        value = -1.0
    if unit not in _UNITS or not np.isfinite(value) or value <= 0:
        raise SubdivInputError(f"max_memory {text!r}: give a size such as 512M, 8G or 1.5GiB (or 'none')",
                               option="max_memory", value=text)
    return int(value * _UNITS[unit])


def memory_limit(value) -> int | None:
    """A ``max_memory`` argument as bytes, or None for no limit.

    None, 0, infinity and the strings of :func:`parse_size` ("none", "0") mean no limit; a number of bytes
    >= 0, or a size string as the CLI's ``--max-memory`` takes ("512M", "8G", "1.5GiB"). Anything else
    (negative, NaN, another type) is refused with :class:`SubdivInputError` (``option`` "max_memory")."""
    if value is None:
        return None
    if isinstance(value, str):
        return parse_size(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise SubdivInputError(f"max_memory must be a number of bytes, a size such as '8G' or None, got {value!r}",
                               option="max_memory", value=value)
    number = float(value)
    if math.isnan(number) or number < 0:
        raise SubdivInputError(f"max_memory {value!r} is not a size: give bytes >= 0, a size such as '8G', or "
                               "None for no limit", option="max_memory", value=value)
    if number == 0 or math.isinf(number):
        return None
    return int(value)


def format_bytes(n: int) -> str:
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"
