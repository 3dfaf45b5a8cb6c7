"""Subdivision rules as pure functions (docs/rules.md sections 0 to 5).

Each function takes the parameters of a local neighbourhood (valence, crease degree ``k``, sector angle
``alpha`` or ``theta``, face sizes, sharpness or fractional weights; scalars or numpy arrays, one entry per
row) and returns stencil weights in float64. None of them sees a mesh, as in OpenSubdiv's
``sdc/catmarkScheme.h`` and ``sdc/loopScheme.h``: the table builder (:mod:`warp_subdiv.tables`) decides which
class each child vertex is, gathers the neighbourhood indices and lays out the weights these functions give.

The rules come in two forms:

* scalar weights of one rule (``*_weights``: e.g. the centre and each neighbour of Loop's interior rule);
* role masks: a :class:`VertexMask` or :class:`EdgeMask` holds, per row, the weight of each role in the
  parent neighbourhood (centre, edge neighbours, face points or face neighbours; an edge's two endpoints and
  its wings). The ``*_mask`` functions build the mask of one vertex or edge class; :func:`ring_mask` and
  :func:`expand_edge_face_points` write Catmull-Clark's face points out over parent vertices;
  :func:`crease_neighbour_edge_mask` applies the paper's gamma(theta) endpoint shift; the semi-sharp blends
  (:func:`transition_weights`, :func:`semi_sharp_edge_weights`) scale the masks they combine.

Which rule a vertex follows as sharpness decays is :mod:`warp_subdiv.rules.crease`'s business.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOOP = "loop"
CATMULL_CLARK = "catmull-clark"
SCHEMES = (CATMULL_CLARK, LOOP)

#: Smallest distance of a corner sector angle from 0 and from pi (docs/rules.md section 2: k*theta != pi).
ALPHA_EPSILON = 1e-4

#: A corner sector of two or more faces whose crease edges are within STRAIGHT_EPSILON (5 degrees) of a straight
#: line seen in the plane of its own faces, and within STRAIGHT_EPSILON_3D (20 degrees) in space, is a straight
#: sector (docs/rules.md section 2.1). Radians.
STRAIGHT_EPSILON = np.pi / 36
STRAIGHT_EPSILON_3D = np.pi / 9

# vertex classes (docs/rules.md section 1)
SMOOTH, DART, CREASE, CORNER = 0, 1, 2, 3
VERTEX_CLASS_NAMES = {SMOOTH: "interior", DART: "dart", CREASE: "crease", CORNER: "corner"}

# sector kinds (docs/rules.md section 2; straight: a corner sector whose creases are collinear, section 2.1)
SECTOR_CREASE, SECTOR_CONVEX, SECTOR_CONCAVE, SECTOR_STRAIGHT = 0, 1, 2, 3


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
    docs/rules.md's (1 - 7/(4n)) c + 3/(2n^2) sum p_i + 1/(4n^2) sum q_i once the face points are expanded.
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
    """gamma(theta) of the crease- and corner-neighbour edge rules (docs/rules.md section 0).

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

    With the smooth endpoint weights w (Loop 3/8, CC 1/4), the rule of docs/rules.md section 4 is
    w - shift on the crease/corner vertex c and w + shift on the non-crease endpoint, the wings unchanged.
    Zero at the regular crease (Loop k = 3, CC k = 2), where the standard rule is recovered.
    """
    return gamma(scheme, theta) - 0.375


def tagged_edge_move(shift_a, shift_b, tagged_a, tagged_b):
    """Weight a crease/corner-neighbour edge rule moves from endpoint a to endpoint b (docs/rules.md section 4).

    ``shift_*`` is :func:`edge_gamma_shift` of the endpoint's sector (ignored where the endpoint is not
    tagged); with both endpoints tagged the move is that of the average of the two one-sided rules
    (docs/rules.md section 1)."""
    shift_a = np.asarray(shift_a, dtype=np.float64) * np.asarray(tagged_a)
    shift_b = np.asarray(shift_b, dtype=np.float64) * np.asarray(tagged_b)
    count = np.maximum(np.asarray(tagged_a, dtype=np.int64) + np.asarray(tagged_b, dtype=np.int64), 1)
    return (shift_a - shift_b) / count


def sector_theta(kind, k, alpha=None):
    """theta of a sector (docs/rules.md section 2): pi/k (smooth crease and straight sector), alpha/k (convex),
    (2 pi - alpha)/k (concave).

    ``alpha`` is the angle between the sector's two crease edges, clamped to [eps, pi - eps] so that
    k*theta != pi for corners.
    """
    kind = np.asarray(kind)
    k = np.asarray(k, dtype=np.float64)
    if alpha is None:
        alpha = np.full(np.shape(k), np.pi / 2)
    a = np.clip(np.asarray(alpha, dtype=np.float64), ALPHA_EPSILON, np.pi - ALPHA_EPSILON)
    return np.where(
        (kind == SECTOR_CREASE) | (kind == SECTOR_STRAIGHT),
        np.pi / k,
        np.where(kind == SECTOR_CONVEX, a / k, (2.0 * np.pi - a) / k),
    )


# --------------------------------------------------------------------------------------------------------
# role masks: the rules above as weights per role of a neighbourhood, one entry per row


def _rows(value, count) -> np.ndarray:
    """A writable float64 array of ``count`` rows holding ``value`` (a scalar or one value per row)."""
    return np.array(np.broadcast_to(np.asarray(value, dtype=np.float64), (count,)))


@dataclass
class VertexMask:
    """The rule of one class of vertex child by role, one weight per row for each role.

    ``centre``: the parent vertex itself; ``edge``: each edge neighbour the rule uses (every ring vertex for
    the smooth rule, the two crease neighbours for the crease rule); ``face``: each new face point around
    the vertex (Catmull-Clark's smooth rule; 0 for the other rules and for Loop). :func:`ring_mask` writes
    the face points out over the parent vertices of the ring."""

    centre: np.ndarray
    edge: np.ndarray
    face: np.ndarray

    def scaled(self, weight) -> "VertexMask":
        """The mask times ``weight`` (a scalar or one per row): one part of a blend of two rules."""
        return VertexMask(self.centre * weight, self.edge * weight, self.face * weight)


@dataclass
class RingMask:
    """A vertex rule written out over the parent vertices of each row's ring, one slot per incident face.

    ``centre`` (R,): the vertex itself, its shares of the face points included. Per slot (the vertex's
    corner in one of its faces; ``slot_row`` (slots,) is the row it belongs to): ``edge`` weighs the edge
    neighbour that follows the corner in that face (the edge term plus the shares of the face points on both
    sides of the edge), ``face`` each other vertex of that face (neither the centre nor one of its two edge
    neighbours in the face; Loop's triangles have none): its share of the face point."""

    centre: np.ndarray
    slot_row: np.ndarray
    edge: np.ndarray
    face: np.ndarray

    def scaled(self, weight) -> "RingMask":
        """The mask times ``weight`` (a scalar or one per row)."""
        w = np.broadcast_to(np.asarray(weight, dtype=np.float64), self.centre.shape)
        per_slot = w[self.slot_row]
        return RingMask(self.centre * w, self.slot_row, self.edge * per_slot, self.face * per_slot)


@dataclass
class EdgeMask:
    """The rule of one class of edge child by role, one weight per row for each role.

    ``end_a``/``end_b``: the edge's endpoints (in the level's ``edge_verts`` order); ``wing_0``/``wing_1``:
    each vertex of the face on the edge's first/second side other than the endpoints (Loop: the vertex
    opposite the edge). In Catmull-Clark's rules as written the wings are the two new face points instead;
    :func:`expand_edge_face_points` writes them out over the faces' vertices."""

    end_a: np.ndarray
    end_b: np.ndarray
    wing_0: np.ndarray
    wing_1: np.ndarray

    def scaled(self, weight) -> "EdgeMask":
        """The mask times ``weight`` (a scalar or one per row): one part of a blend of two rules."""
        return EdgeMask(self.end_a * weight, self.end_b * weight, self.wing_0 * weight, self.wing_1 * weight)

    def take(self, rows) -> "EdgeMask":
        """The mask of the given rows only."""
        return EdgeMask(self.end_a[rows], self.end_b[rows], self.wing_0[rows], self.wing_1[rows])


def corner_vertex_mask(count: int) -> VertexMask:
    """Corner rule for ``count`` rows: the vertex stays where it is (docs/rules.md section 3)."""
    return VertexMask(_rows(corner_vertex_weights(), count), _rows(0.0, count), _rows(0.0, count))


def crease_vertex_mask(count: int) -> VertexMask:
    """Crease rule for ``count`` rows: 3/4 on the vertex, 1/8 on each of its two crease neighbours."""
    centre, neighbour = crease_vertex_weights()
    return VertexMask(_rows(centre, count), _rows(neighbour, count), _rows(0.0, count))


def smooth_vertex_mask(scheme: str, valence, loop_beta_variant: str = "loop") -> VertexMask:
    """Interior (and dart) vertex rule of the given valences (docs/rules.md section 3).

    Loop: 1 - n beta on the vertex, beta on each ring vertex, no face points. Catmull-Clark: (n-2)/n on the
    vertex, 1/n^2 on each edge neighbour and 1/n^2 on each new face point."""
    n = np.asarray(valence, dtype=np.float64)
    count = n.size
    if scheme == LOOP:
        centre, edge = loop_interior_vertex_weights(n, loop_beta_variant)
        face = 0.0
    elif scheme == CATMULL_CLARK:
        centre, edge, face = catmull_clark_interior_vertex_weights(n)
    else:
        raise ValueError(f"unknown scheme {scheme!r}")
    return VertexMask(_rows(centre, count), _rows(edge, count), _rows(face, count))


def ring_mask(mask: VertexMask, slot_row, face_size=None, other_face_size=None) -> RingMask:
    """``mask`` written out over the parent vertices of each row's ring (docs/rules.md sections 3 and 5).

    ``slot_row`` (slots,) gives the row of each slot; ``face_size`` the size of each slot's face and
    ``other_face_size`` the size of the face across the slot's edge (the edge from the vertex to the slot's
    edge neighbour). Every face point is its face's centroid, so it hands 1/m of its weight to each of the m
    vertices of its face: the centre once per face, each edge neighbour once from each of the two faces
    beside its edge, each other vertex once. Without face sizes (rules without face points) the edge weight
    is copied to every slot."""
    row = np.asarray(slot_row, dtype=np.int64)
    edge = mask.edge[row]
    if face_size is None:
        return RingMask(mask.centre, row, edge, np.zeros(len(row)))
    face = mask.face[row] / face_size
    centre = mask.centre + np.bincount(row, weights=face, minlength=len(mask.centre))
    return RingMask(centre, row, edge + face + mask.face[row] / other_face_size, face)


def crease_edge_mask(count: int) -> EdgeMask:
    """Crease edge rule for ``count`` rows: the midpoint (docs/rules.md section 4)."""
    a, b = crease_edge_weights()
    return EdgeMask(_rows(a, count), _rows(b, count), _rows(0.0, count), _rows(0.0, count))


def smooth_edge_mask(scheme: str, count: int) -> EdgeMask:
    """Smooth edge rule for ``count`` rows (docs/rules.md section 4): Loop 3/8 on the endpoints and 1/8 on
    each opposite vertex; Catmull-Clark 1/4 on the endpoints and 1/4 on each of the two new face points."""
    end, wing = smooth_edge_weights(scheme)
    return EdgeMask(_rows(end, count), _rows(end, count), _rows(wing, count), _rows(wing, count))


def catmull_clark_edge_mask(face_size_0, face_size_1, smooth_triangles: bool = False) -> EdgeMask:
    """Smooth Catmull-Clark edge rule between faces of the given sizes, face points as wings.

    1/4 everywhere, or OpenSubdiv's "smooth triangles" weights where a triangle touches the edge (see
    :func:`catmull_clark_edge_weights`; docs/rules.md section 15.5)."""
    end, face = catmull_clark_edge_weights(face_size_0, face_size_1, smooth_triangles)
    count = np.size(end)
    return EdgeMask(_rows(end, count), _rows(end, count), _rows(face, count), _rows(face, count))


def crease_neighbour_edge_mask(scheme: str, mask: EdgeMask, theta_a, theta_b, tagged_a, tagged_b) -> EdgeMask:
    """The paper's crease- and corner-neighbour edge rule: ``mask`` (the smooth rule of the edge) with
    gamma(theta) weight moved between the endpoints (docs/rules.md section 4).

    ``theta_*`` is the sector angle of the endpoint's sector that holds the edge (NaN where it has none),
    ``tagged_*`` whether the endpoint is a crease or corner vertex. A tagged endpoint c keeps w - shift and
    the other endpoint gets w + shift, shift = gamma(theta) - 3/8, the wings unchanged; with both endpoints
    tagged the two one-sided rules are averaged. At the regular crease (Loop k = 3, Catmull-Clark k = 2) the
    shift is 0 and the smooth rule is recovered."""
    shift_a = np.nan_to_num(edge_gamma_shift(scheme, theta_a))
    shift_b = np.nan_to_num(edge_gamma_shift(scheme, theta_b))
    move = tagged_edge_move(shift_a, shift_b, tagged_a, tagged_b)
    return EdgeMask(mask.end_a - move, mask.end_b + move, mask.wing_0, mask.wing_1)


def expand_edge_face_points(mask: EdgeMask, face_size_0, face_size_1) -> EdgeMask:
    """A Catmull-Clark edge mask with its two face-point wings written out over the faces' vertices.

    Each face point is its face's centroid: both endpoints get 1/m_0 of wing 0 and 1/m_1 of wing 1, and
    every other vertex of face j gets 1/m_j of wing j (docs/rules.md sections 4 and 5)."""
    w0 = mask.wing_0 / face_size_0
    w1 = mask.wing_1 / face_size_1
    return EdgeMask(mask.end_a + w0 + w1, mask.end_b + w0 + w1, w0, w1)


# --------------------------------------------------------------------------------------------------------
# semi-sharp blends (OpenSubdiv's Sdc::Scheme; the weights come from warp_subdiv.rules.crease)


def transition_weights(fractional_weight):
    """(parent rule weight, child rule weight) of a vertex whose rule changes during the step.

    The child is the parent rule's mask times the fractional weight w (from
    :func:`warp_subdiv.rules.crease.fractional_weight`) plus the child rule's mask times 1 - w; a vertex whose rule
    does not change has w = 1 (docs/rules.md section 15.2)."""
    w = np.asarray(fractional_weight, dtype=np.float64)
    return w, 1.0 - w


def transition_blend(parent, child, fractional_weight):
    """The two parts of a transitional vertex mask: (``parent`` times w, ``child`` times 1 - w).

    ``parent`` and ``child`` are masks (:class:`VertexMask`, :class:`RingMask`) of the same rows; a stencil
    row lists both parts over their own neighbours."""
    w_parent, w_child = transition_weights(fractional_weight)
    return parent.scaled(w_parent), child.scaled(w_child)


def semi_sharp_edge_weights(sharpness):
    """(crease rule weight, smooth rule weight) of the child of an edge of the given sharpness.

    A semi-sharp edge whose sharpness runs out during the step gives its child s times the crease rule plus
    1 - s times the smooth rule; sharpness 1 is the crease rule alone, 0 the smooth rule alone (docs/rules.md
    section 15.2)."""
    s = np.asarray(sharpness, dtype=np.float64)
    return s, 1.0 - s


def semi_sharp_edge_blend(crease: EdgeMask, smooth: EdgeMask, sharpness):
    """The two parts of a semi-sharp edge mask: (``crease`` times s, ``smooth`` times 1 - s)."""
    w_crease, w_smooth = semi_sharp_edge_weights(sharpness)
    return crease.scaled(w_crease), smooth.scaled(w_smooth)
