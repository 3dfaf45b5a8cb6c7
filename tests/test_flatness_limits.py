"""Limits under a numeric flatness at crease ends: three creases meeting at a corner of a wavy grid, each
ending in a dart. With flatness=1.0 the limit masks (crease l_cross(s), dart, boundary crease) are exact, so
``Refiner.limit_points`` / ``limit_normals`` of levels 0 and 2 equal ``LimitSurface`` at the control vertices
to round-off, and the surface's own normal at a crease end does not depend on the tree's depth."""
import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv.topology import base_level


def y_creased_grid(scheme, n=6, seed=3):
    """A wavy n x n grid (quads, or each quad split in two triangles) whose centre vertex is a corner of three
    creases of two edges each (left, up, right); returns the mesh, the corner and the three crease ends."""
    rng = np.random.default_rng(seed)
    points = np.array([[x, y, 0.15 * rng.standard_normal()] for y in range(n + 1) for x in range(n + 1)], float)

    def vid(x, y):
        return y * (n + 1) + x

    faces = []
    for y in range(n):
        for x in range(n):
            quad = [vid(x, y), vid(x + 1, y), vid(x + 1, y + 1), vid(x, y + 1)]
            faces += [quad] if scheme == "catmull-clark" else [quad[:3], [quad[0], quad[2], quad[3]]]
    c = n // 2
    arms = [(-1, 0), (0, 1), (1, 0)]
    creases = [[vid(c + i * dx, c + i * dy), vid(c + (i + 1) * dx, c + (i + 1) * dy)] for dx, dy in arms
               for i in range(2)]
    faces = np.array(faces)
    mesh = ws.Mesh(points, [len(f) for f in faces], faces.reshape(-1), creases=creases)
    return mesh, vid(c, c), [vid(c + 2 * dx, c + 2 * dy) for dx, dy in arms]


def vertex_queries(surface, mesh):
    """(faces, u, v) of every control vertex, each at its first face."""
    n = int(mesh.face_vertex_counts[0])
    fvi = mesh.face_vertex_indices.reshape(-1, n)
    faces = np.array([np.flatnonzero((fvi == v).any(1))[0] for v in range(mesh.num_vertices)])
    corners = np.array([np.flatnonzero(fvi[f] == v)[0] for v, f in enumerate(faces)])
    uv = surface.vertex_uv(faces, corners)
    return faces, uv[:, 0], uv[:, 1]


@pytest.mark.parametrize("scheme", ["catmull-clark", "loop"])
def test_numeric_flatness_limits_are_exact_at_crease_ends(scheme):
    mesh, corner, ends = y_creased_grid(scheme)
    surface = ws.LimitSurface(mesh, scheme=scheme, flatness=1.0)
    f, u, v = vertex_queries(surface, mesh)
    at = surface.evaluate(f, u, v)
    level = base_level(mesh, scheme, "edge-and-corner", "piecewise-smooth")
    one_sector = np.bincount(level.sector_vertex, minlength=mesh.num_vertices) <= 1  # one tangent plane
    for levels in (0, 2):
        refined = ws.refine(mesh, levels, scheme=scheme, flatness=1.0, precision="float64", device="cpu")
        np.testing.assert_allclose(refined.limit_points()[:mesh.num_vertices], at.points, rtol=0, atol=1e-12)
        normals = refined.limit_normals()[:mesh.num_vertices]
        np.testing.assert_allclose(normals[one_sector], at.normals[one_sector], rtol=0, atol=1e-10)
    deeper = ws.LimitSurface(mesh, scheme=scheme, flatness=1.0, depth=11).evaluate(f[ends], u[ends], v[ends])
    np.testing.assert_allclose(deeper.normals, at.normals[ends], rtol=0, atol=1e-10)
