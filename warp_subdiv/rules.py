"""Subdivision rules as pure functions (RULES.md sections 0 to 5).

Each function takes the parameters of a local neighbourhood (valence, crease degree ``k``, sector angle
``alpha`` or ``theta``; scalars or numpy arrays) and returns stencil weights in float64. None of them sees a
mesh: the table builder gathers neighbourhoods and asks these functions for their weights.
"""
from __future__ import annotations

import numpy as np

LOOP = "loop"
CATMULL_CLARK = "catmull-clark"
SCHEMES = (CATMULL_CLARK, LOOP)

#: Smallest distance of a corner sector angle from 0 and from pi (RULES.md section 2: k*theta != pi).
ALPHA_EPSILON = 1e-4

# vertex classes (RULES.md section 1)
SMOOTH, DART, CREASE, CORNER = 0, 1, 2, 3
VERTEX_CLASS_NAMES = {SMOOTH: "interior", DART: "dart", CREASE: "crease", CORNER: "corner"}

# sector kinds (RULES.md section 2)
SECTOR_CREASE, SECTOR_CONVEX, SECTOR_CONCAVE = 0, 1, 2


def loop_beta(valence, variant: str = "loop"):
    """Loop's ring weight beta for an interior vertex of the given valence.

    ``"loop"``: Loop's original (1/k)(5/8 - (3/8 + cos(2 pi/k)/4)^2) (OpenSubdiv's choice);
    ``"warren"``: the paper's 3/(8k) for k > 3 and 3/16 for k = 3.
    """
    k = np.asarray(valence, dtype=np.float64)
    if variant == "loop":
        return (0.625 - (0.375 + 0.25 * np.cos(2.0 * np.pi / k)) ** 2) / k
    if variant == "warren":
        return np.where(k == 3, 3.0 / 16.0, 3.0 / (8.0 * k))
    raise ValueError(f"unknown Loop beta variant {variant!r}; use 'loop' or 'warren'")


def loop_interior_vertex_weights(valence, variant: str = "loop"):
    """(centre weight, weight of each edge neighbour) of Loop's interior (and dart) vertex rule."""
    beta = loop_beta(valence, variant)
    return 1.0 - np.asarray(valence, dtype=np.float64) * beta, beta


def catmull_clark_interior_vertex_weights(valence):
    """(centre, each edge neighbour, each new face point) of the Catmull-Clark interior vertex rule.

    c' = ((n-2)/n) c + (1/n^2) sum p_i + (1/n^2) sum f_i with f_i the new face points; for quads this is
    RULES.md's (1 - 7/(4n)) c + 3/(2n^2) sum p_i + 1/(4n^2) sum q_i once the face points are expanded.
    """
    n = np.asarray(valence, dtype=np.float64)
    return (n - 2.0) / n, 1.0 / (n * n), 1.0 / (n * n)


def crease_vertex_weights():
    """(centre, each of the two crease neighbours): the cubic B-spline rule 3/4, 1/8, 1/8."""
    return 0.75, 0.125


def corner_vertex_weights():
    """Corners interpolate: the centre keeps weight 1."""
    return 1.0


def crease_edge_weights():
    """Weights of the two endpoints of a crease edge: the midpoint."""
    return 0.5, 0.5


def smooth_edge_weights(scheme: str):
    """(each endpoint, each 'wing' term) of the smooth edge rule.

    Loop: 3/8 on the endpoints, 1/8 on each opposite vertex.
    Catmull-Clark: 1/4 on the endpoints, 1/4 on each of the two new face points.
    """
    if scheme == LOOP:
        return 0.375, 0.125
    if scheme == CATMULL_CLARK:
        return 0.25, 0.25
    raise ValueError(f"unknown scheme {scheme!r}")


#: OpenSubdiv's TRI_SUB_SMOOTH face-point weight for a triangle next to a smooth Catmull-Clark edge.
SMOOTH_TRIANGLE_FACE_WEIGHT = 0.470


def catmull_clark_edge_weights(face_size_0, face_size_1, smooth_triangles: bool = False):
    """(each endpoint, each of the two face points) of the smooth Catmull-Clark edge rule.

    Plain: 1/4 and 1/4. With "smooth triangles" (OpenSubdiv's TRI_SUB_SMOOTH, USD's
    triangleSubdivisionRule = "smooth") and a triangle on either side, both face points weigh the mean of
    0.470 per triangle and 1/4 per other face, and the endpoints share what is left."""
    m0 = np.asarray(face_size_0)
    m1 = np.asarray(face_size_1)
    if not smooth_triangles:
        shape = np.broadcast(m0, m1).shape
        return np.full(shape, 0.25), np.full(shape, 0.25)
    w0 = np.where(m0 == 3, SMOOTH_TRIANGLE_FACE_WEIGHT, 0.25)
    w1 = np.where(m1 == 3, SMOOTH_TRIANGLE_FACE_WEIGHT, 0.25)
    face = 0.5 * (w0 + w1)
    return 0.5 * (1.0 - 2.0 * face), face


def face_point_weights(num_vertices):
    """Each vertex of an n-gon weighs 1/n in its face point (the centroid)."""
    return 1.0 / np.asarray(num_vertices, dtype=np.float64)


def gamma(scheme: str, theta):
    """gamma(theta) of the crease- and corner-neighbour edge rules (RULES.md section 0).

    Loop 1/2 - cos(theta)/4, Catmull-Clark 3/8 - cos(theta)/4. It weighs the NON-crease endpoint.
    """
    theta = np.asarray(theta, dtype=np.float64)
    if scheme == LOOP:
        return 0.5 - 0.25 * np.cos(theta)
    if scheme == CATMULL_CLARK:
        return 0.375 - 0.25 * np.cos(theta)
    raise ValueError(f"unknown scheme {scheme!r}")


def edge_gamma_shift(scheme: str, theta):
    """gamma(theta) - 3/8: how far a crease/corner-neighbour edge rule moves weight off the tagged endpoint.

    With the smooth endpoint weights w (Loop 3/8, CC 1/4), the rule of RULES.md section 4 is
    w - shift on the crease/corner vertex c and w + shift on the non-crease endpoint, the wings unchanged.
    Zero at the regular crease (Loop k = 3, CC k = 2), where the standard rule is recovered.
    """
    return gamma(scheme, theta) - 0.375


def tagged_edge_endpoint_weights(scheme: str, shift_a, shift_b, tagged_a, tagged_b):
    """Endpoint weights (w_a, w_b) of a non-crease edge whose endpoints may be crease or corner vertices.

    ``shift_*`` is :func:`edge_gamma_shift` of the endpoint's sector (0 when untagged); with both endpoints
    tagged the result is the average of the two one-sided rules (RULES.md section 1).
    """
    w, _ = smooth_edge_weights(scheme)
    shift_a = np.asarray(shift_a, dtype=np.float64) * np.asarray(tagged_a)
    shift_b = np.asarray(shift_b, dtype=np.float64) * np.asarray(tagged_b)
    count = np.maximum(np.asarray(tagged_a, dtype=np.int64) + np.asarray(tagged_b, dtype=np.int64), 1)
    move = (shift_a - shift_b) / count
    return w - move, w + move


def sector_theta(kind, k, alpha=None):
    """theta of a sector (RULES.md section 2): pi/k (smooth crease), alpha/k (convex), (2 pi - alpha)/k (concave).

    ``alpha`` is the angle between the sector's two crease edges, clamped to [eps, pi - eps] so that
    k*theta != pi for corners.
    """
    kind = np.asarray(kind)
    k = np.asarray(k, dtype=np.float64)
    if alpha is None:
        alpha = np.full(np.shape(k), np.pi / 2)
    a = np.clip(np.asarray(alpha, dtype=np.float64), ALPHA_EPSILON, np.pi - ALPHA_EPSILON)
    return np.where(
        kind == SECTOR_CREASE,
        np.pi / k,
        np.where(kind == SECTOR_CONVEX, a / k, (2.0 * np.pi - a) / k),
    )
