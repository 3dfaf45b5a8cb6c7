"""Shared fixtures: test meshes, reference data and the devices to run on (CPU always, CUDA when present)."""
import contextlib
import os

import numpy as np
import pytest
import warp as wp

wp.config.log_level = 30  # keep Warp's start-up and module-load lines out of the test log

DATA = os.path.join(os.path.dirname(__file__), "data")
MESHES = os.path.join(DATA, "meshes")


def mesh_path(name: str) -> str:
    return os.path.join(MESHES, name if name.endswith(".obj") else name + ".obj")


def load_mesh(name: str):
    """A test mesh from tests/data/meshes (with its side files) as a warp_subdiv.Mesh."""
    from warp_subdiv.io.obj import read_obj

    return read_obj(mesh_path(name)).mesh


def fin_mesh(triangles: bool = False):
    """Three sheets of two quads meeting along a spine (two non-manifold edges, the middle vertex in six faces),
    as a warp_subdiv.Mesh; each quad split in two triangles with ``triangles``."""
    import warp_subdiv as ws

    points, faces = [[0, 0, 0], [1, 0, 0], [2, 0, 0]], []
    for sheet, angle in enumerate([0.0, 2.1, 4.2]):
        out = np.array([0, np.cos(angle), np.sin(angle)]) * (1 + 0.1 * sheet)
        x0 = len(points)
        points += [(np.array([i, 0, 0]) + out).tolist() for i in range(3)]
        pair = [[0, 1, x0 + 1, x0], [1, 2, x0 + 2, x0 + 1]]
        faces += pair if sheet % 2 == 0 else [f[::-1] for f in pair]
    if triangles:
        faces = [t for a, b, c, d in faces for t in ([a, b, c], [a, c, d])]
    return ws.Mesh(np.array(points, dtype=float), [len(faces[0])] * len(faces), np.array(faces).reshape(-1))

def devices():
    out = ["cpu"]
    if wp.get_cuda_device_count() > 0:
        out.append("cuda")
    return out


@pytest.fixture(params=devices())
def device(request):
    """Every device-dependent test runs on the CPU, and on CUDA when a GPU is present."""
    return request.param


def dense(table, num_sources=None):
    """A stencil table as a dense (rows, sources) matrix, duplicates summed."""
    n = table.num_sources if num_sources is None else num_sources
    out = np.zeros((table.num_rows, n))
    rows = np.repeat(np.arange(table.num_rows), np.diff(table.offsets.astype(np.int64)))
    np.add.at(out, (rows, table.indices.astype(np.int64)), table.weights)
    return out


@contextlib.contextmanager
def dask_client(**cluster):
    """A Dask client of a ``distributed.LocalCluster(**cluster)`` (skips without Dask). Dask's nannies set
    MALLOC_TRIM_THRESHOLD_, OMP_NUM_THREADS and others in this process's environment; they are restored
    afterwards so later tests (and their subprocesses) run as a user's process would."""
    distributed = pytest.importorskip("distributed")
    saved = dict(os.environ)
    local = distributed.LocalCluster(threads_per_worker=1, dashboard_address=None, silence_logs=50, **cluster)
    client = distributed.Client(local)
    try:
        yield client
    finally:
        client.close()
        local.close()
        os.environ.clear()
        os.environ.update(saved)
