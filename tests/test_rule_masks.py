"""The pure role masks of warp_subdiv.rules and the sharpness arithmetic of warp_subdiv.rules.crease, without a mesh.

Every mask is checked on parameters alone: affine invariance (weights sum to 1 over the whole neighbourhood),
the end points of the semi-sharp blends, and the regular cases where a modified rule equals the plain one.
"""
import numpy as np
import pytest

from warp_subdiv.rules import crease
from warp_subdiv.rules import limit_masks as masks
from warp_subdiv.rules import weights as rules
from warp_subdiv.rules.weights import CATMULL_CLARK, CORNER, CREASE, DART, LOOP, SMOOTH

VALENCES = np.arange(3, 13)


def vertex_sum(mask, valence):
    """Total weight of a vertex mask whose rule uses ``valence`` edge neighbours and face points."""
    return mask.centre + valence * mask.edge + valence * mask.face


def ring_sum(ring, face_size):
    """Total weight of a ring mask: centre, each slot's edge neighbour and its face's m - 3 other vertices."""
    per_slot = ring.edge + (face_size - 3) * ring.face
    return ring.centre + np.bincount(ring.slot_row, weights=per_slot, minlength=len(ring.centre))


def edge_sum(mask, m0=3, m1=3):
    """Total weight of an edge mask written out over faces of sizes m0 and m1 (Loop: triangles)."""
    return mask.end_a + mask.end_b + (m0 - 2) * mask.wing_0 + (m1 - 2) * mask.wing_1


def assert_masks_equal(got, expected):
    """Two masks of the same kind have the same weights in every role."""
    assert type(got) is type(expected)
    for name, value in vars(expected).items():
        np.testing.assert_allclose(getattr(got, name), value, rtol=0, atol=1e-15, err_msg=name)


@pytest.mark.parametrize("scheme,variant", [(LOOP, "loop"), (LOOP, "warren"), (CATMULL_CLARK, "loop")])
def test_vertex_masks_sum_to_one(scheme, variant):
    """Smooth (every valence), crease (two neighbours) and corner vertex masks are affine."""
    np.testing.assert_allclose(vertex_sum(rules.smooth_vertex_mask(scheme, VALENCES, variant), VALENCES), 1.0,
                               atol=1e-15)
    np.testing.assert_allclose(vertex_sum(rules.crease_vertex_mask(4), 2), 1.0, atol=0)
    np.testing.assert_allclose(vertex_sum(rules.corner_vertex_mask(4), 0), 1.0, atol=0)
    assert np.all(rules.corner_vertex_mask(4).edge == 0) and np.all(rules.crease_vertex_mask(4).face == 0)


def test_loop_smooth_vertex_mask_values():
    """Loop's smooth mask: Warren's 3/16 at valence 3 and Loop's 1/16 at valence 6 on each ring vertex."""
    assert rules.smooth_vertex_mask(LOOP, [3], "warren").edge[0] == pytest.approx(3 / 16)
    m = rules.smooth_vertex_mask(LOOP, [6], "loop")
    assert m.edge[0] == pytest.approx(1 / 16) and m.centre[0] == pytest.approx(10 / 16)
    assert np.all(m.face == 0)


def test_ring_mask_of_regular_quads_is_the_expanded_catmull_clark_rule():
    """With quads all round, the face points written out give (1 - 7/(4n)) c + 3/(2n^2) p_i + 1/(4n^2) q_i."""
    for n in VALENCES:
        mask = rules.smooth_vertex_mask(CATMULL_CLARK, [n])
        row = np.zeros(n, dtype=np.int64)
        quads = np.full(n, 4)
        ring = rules.ring_mask(mask, row, quads, quads)
        assert ring.centre[0] == pytest.approx(1 - 7 / (4 * n))
        np.testing.assert_allclose(ring.edge, 3 / (2 * n * n))
        np.testing.assert_allclose(ring.face, 1 / (4 * n * n))
        np.testing.assert_allclose(ring_sum(ring, quads), 1.0, atol=1e-15)


def test_ring_mask_sums_to_one_around_mixed_polygons():
    """Around faces of mixed sizes (the face across slot i's edge is slot i-1's face) the ring mask is affine."""
    rng = np.random.default_rng(7)
    for n in VALENCES:
        sizes = rng.integers(3, 8, size=n)
        mask = rules.smooth_vertex_mask(CATMULL_CLARK, [n])
        ring = rules.ring_mask(mask, np.zeros(n, dtype=np.int64), sizes, np.roll(sizes, 1))
        np.testing.assert_allclose(ring_sum(ring, sizes), 1.0, atol=1e-15)


def test_ring_mask_without_face_points_copies_the_edge_weight():
    """Loop's ring mask: the centre unchanged, beta on every slot, no face neighbours."""
    mask = rules.smooth_vertex_mask(LOOP, [5, 7])
    row = np.repeat([0, 1], [5, 7])
    ring = rules.ring_mask(mask, row)
    np.testing.assert_array_equal(ring.centre, mask.centre)
    np.testing.assert_array_equal(ring.edge, mask.edge[row])
    assert np.all(ring.face == 0)
    np.testing.assert_allclose(ring_sum(ring, np.full(12, 3)), 1.0, atol=1e-15)


@pytest.mark.parametrize("smooth_triangles", [False, True])
def test_edge_masks_sum_to_one(smooth_triangles):
    """Crease, Loop smooth and Catmull-Clark smooth edge masks (face points written out) are affine."""
    np.testing.assert_allclose(edge_sum(rules.crease_edge_mask(3), 2, 2), 1.0, atol=0)
    np.testing.assert_allclose(edge_sum(rules.smooth_edge_mask(LOOP, 3)), 1.0, atol=0)
    m0, m1 = np.array([3, 4, 4, 5, 3]), np.array([3, 4, 3, 6, 7])
    cc = rules.catmull_clark_edge_mask(m0, m1, smooth_triangles)
    np.testing.assert_allclose(cc.end_a + cc.end_b + cc.wing_0 + cc.wing_1, 1.0, atol=1e-15)
    np.testing.assert_allclose(edge_sum(rules.expand_edge_face_points(cc, m0, m1), m0, m1), 1.0, atol=1e-15)


def test_catmull_clark_edge_mask_between_quads():
    """Between quads the written-out Catmull-Clark edge rule is 3/8 on the endpoints and 1/16 on the others."""
    quads = np.full(2, 4)
    m = rules.expand_edge_face_points(rules.catmull_clark_edge_mask(quads, quads), quads, quads)
    np.testing.assert_allclose(m.end_a, 3 / 8)
    np.testing.assert_allclose(m.end_b, 3 / 8)
    np.testing.assert_allclose(m.wing_0, 1 / 16)
    np.testing.assert_allclose(m.wing_1, 1 / 16)
    assert_masks_equal(rules.catmull_clark_edge_mask(quads, quads), rules.smooth_edge_mask(CATMULL_CLARK, 2))


@pytest.mark.parametrize("fraction", [0.0, 1.0, 0.3])
def test_transition_blend_end_points(fraction):
    """Fractional weight 1 is the parent rule alone, 0 the child rule alone; any weight stays affine."""
    parent = rules.crease_vertex_mask(2)
    child = rules.smooth_vertex_mask(CATMULL_CLARK, [4, 5])
    first, second = rules.transition_blend(parent, child, fraction)
    if fraction == 1.0:
        assert_masks_equal(first, parent)
        assert np.all(vertex_sum(second, np.array([4, 5])) == 0)
    if fraction == 0.0:
        assert_masks_equal(second, child)
        assert np.all(vertex_sum(first, 2) == 0)
    np.testing.assert_allclose(vertex_sum(first, 2) + vertex_sum(second, np.array([4, 5])), 1.0, atol=1e-15)
    assert rules.transition_weights(fraction) == (fraction, 1.0 - fraction)


def test_transition_blend_per_row_weights():
    """The fractional weight may differ per row; ring masks scale their slots with their row's weight."""
    mask = rules.smooth_vertex_mask(LOOP, [3, 4])
    row = np.repeat([0, 1], [3, 4])
    ring = rules.ring_mask(mask, row)
    w = np.array([0.25, 0.75])
    scaled, rest = rules.transition_blend(ring, ring, w)
    np.testing.assert_allclose(scaled.edge, ring.edge * w[row])
    np.testing.assert_allclose(scaled.edge + rest.edge, ring.edge, atol=1e-16)


@pytest.mark.parametrize("scheme", [LOOP, CATMULL_CLARK])
@pytest.mark.parametrize("sharpness", [0.0, 1.0, 0.6])
def test_semi_sharp_edge_blend_end_points(scheme, sharpness):
    """Sharpness 1 is the crease rule alone, 0 the smooth rule alone; in between the blend stays affine."""
    crease_mask = rules.crease_edge_mask(2)
    smooth = rules.smooth_edge_mask(scheme, 2)
    sharp_part, smooth_part = rules.semi_sharp_edge_blend(crease_mask, smooth, sharpness)
    if sharpness == 1.0:
        assert_masks_equal(sharp_part, crease_mask)
        assert np.all(edge_sum(smooth_part) == 0)
    if sharpness == 0.0:
        assert_masks_equal(smooth_part, smooth)
        assert np.all(edge_sum(sharp_part, 2, 2) == 0)
    total = edge_sum(sharp_part, 2, 2) + (smooth_part.end_a + smooth_part.end_b + smooth_part.wing_0 +
                                          smooth_part.wing_1)
    np.testing.assert_allclose(total, 1.0, atol=1e-15)


@pytest.mark.parametrize("scheme,k", [(LOOP, 3), (CATMULL_CLARK, 2)])
def test_crease_neighbour_rule_at_the_regular_crease_is_the_smooth_rule(scheme, k):
    """At theta = pi/k of the regular crease the gamma(theta) shift vanishes: the smooth edge rule."""
    smooth = rules.smooth_edge_mask(scheme, 3)
    theta = np.full(3, np.pi / k)
    tagged_a, tagged_b = np.array([True, False, True]), np.array([False, True, True])
    got = rules.crease_neighbour_edge_mask(scheme, smooth, theta, theta, tagged_a, tagged_b)
    assert_masks_equal(got, smooth)


@pytest.mark.parametrize("scheme", [LOOP, CATMULL_CLARK])
def test_crease_neighbour_rule_moves_weight_between_the_endpoints(scheme):
    """Off the regular crease weight moves between the endpoints only: the sum and the wings stay; the
    tagged endpoint keeps the smooth weight minus gamma(theta) - 3/8, the rule of both tagged ends is the
    average of the one-sided rules, and untagged endpoints (or no sector: theta NaN) change nothing."""
    smooth = rules.smooth_edge_mask(scheme, 1)
    w = smooth.end_a[0]
    theta_a, theta_b = np.array([0.4]), np.array([2.0])
    shift_a = rules.gamma(scheme, theta_a) - 0.375
    shift_b = rules.gamma(scheme, theta_b) - 0.375
    one = rules.crease_neighbour_edge_mask(scheme, smooth, theta_a, theta_b, [True], [False])
    np.testing.assert_allclose([one.end_a[0], one.end_b[0]], [w - shift_a[0], w + shift_a[0]], atol=1e-15)
    np.testing.assert_array_equal(one.wing_0, smooth.wing_0)
    other = rules.crease_neighbour_edge_mask(scheme, smooth, theta_a, theta_b, [False], [True])
    both = rules.crease_neighbour_edge_mask(scheme, smooth, theta_a, theta_b, [True], [True])
    np.testing.assert_allclose(both.end_a, 0.5 * (one.end_a + other.end_a), atol=1e-15)
    np.testing.assert_allclose(other.end_b, w - shift_b, atol=1e-15)
    for m in (one, other, both):
        np.testing.assert_allclose(edge_sum(m), edge_sum(smooth), atol=1e-15)
    untagged = rules.crease_neighbour_edge_mask(scheme, smooth, [np.nan], [np.nan], [True], [False])
    assert_masks_equal(untagged, smooth)


def test_crease_limit_mask_is_shared():
    """The crease limit mask 2/3, 1/6, 1/6 is affine and is the l0 of every smooth-crease sector mask."""
    centre, neighbour = masks.crease_limit_weights()
    assert centre + 2 * neighbour == pytest.approx(1.0)
    for scheme in (LOOP, CATMULL_CLARK):
        for k in (1, 2, 3, 5):
            m = masks.sector_masks(scheme, np.array([rules.SECTOR_CREASE]), k, np.array([np.pi / k]))
            expected = np.zeros(m.l0.shape[1])
            expected[0], expected[1], expected[1 + k] = centre, neighbour, neighbour
            np.testing.assert_array_equal(m.l0[0], expected)


def test_vertex_rule_from_sharpness_and_counts():
    """Classes from sharpness and sharp-edge counts: none interior, one dart, two crease, more or sharp corner."""
    got = crease.vertex_rule(np.array([0.0, 0.0, 0.0, 0.0, 0.5]), np.array([0, 1, 2, 3, 0]))
    assert got.tolist() == [SMOOTH, DART, CREASE, CORNER, CORNER]


def test_sharpness_decay_and_fractional_weight():
    """A crease vertex with edges of sharpness 0.5 and 2.5 becomes a dart: the parent (crease) rule keeps the
    fractional weight 0.5, the mean sharpness of the features that end in this step."""
    edge_verts = np.array([[0, 1], [0, 2], [0, 3]])
    sharpness = np.array([0.5, 2.5, 0.0])
    vert_sharpness = np.zeros(4)
    np.testing.assert_array_equal(crease.decrement_sharpness(np.array([0.5, 1.0, 2.5, 10.0, 12.0])),
                                  [0.0, 0.0, 1.5, 10.0, 10.0])
    halves = crease.child_edge_sharpness(sharpness, edge_verts, 4, "uniform")
    np.testing.assert_array_equal(halves, [[0.0, 0.0], [1.5, 1.5], [0.0, 0.0]])
    child_vs = crease.decrement_sharpness(vert_sharpness)
    parent_rule = crease.vertex_rule(vert_sharpness, np.array([2, 1, 1, 0]))
    child_rule, edge_child_rule = crease.child_rules(edge_verts, halves, child_vs)
    assert parent_rule[0] == CREASE and child_rule[0] == DART
    assert edge_child_rule.tolist() == [SMOOTH, CREASE, SMOOTH]
    assert crease.vertex_transitions(parent_rule, child_rule).tolist() == [True, False, False, False]
    assert crease.edge_transitions(sharpness > 0, edge_child_rule).tolist() == [True, False, False]
    w = crease.fractional_weight(edge_verts, sharpness, vert_sharpness, halves, child_vs, "uniform")
    assert w[0] == pytest.approx(0.5)
    assert crease.any_semi_sharp(sharpness, vert_sharpness)
    assert not crease.any_semi_sharp(np.array([0.0, 10.0]), np.zeros(2))
