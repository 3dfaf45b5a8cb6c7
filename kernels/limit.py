"""Limit-surface evaluation kernel (:class:`warp_subdiv.limit.LimitSurface`), float64.

One thread per query point: map the base face's (u, v) onto a root of the patch tree (the face itself; a
Catmull-Clark n-gon's sub-face tile; a Loop polygon's fan triangle), descend the tree (quadrants, or a
triangle's corner and middle children) to a leaf, and evaluate its Bezier patch: bicubic (16 control points,
index a + 4 b for the Bernstein polynomials B_a(s) B_b(t)) or quartic triangular (exponents of (1 - s - t, s, t) in
the order of ``warp_subdiv.limit.bezier.TRI_BEZIER_INDEX``). Derivatives are returned
with respect to the base face's (u, v): the descent's scale (2 per level; -2 in a triangle's middle child,
whose frame is turned by 180 degrees) is applied on the way out. Kernels know nothing about subdivision rules.
Where ``exact`` is set, a query whose leaf patch has an entry in ``patch_exact`` (an end cap that the host
evaluates exactly: ``warp_subdiv.limit.exact_caps``) also gets the patch's own (s, t) and the scales (js, jt) in
``out_local``. Each step is a function of its own (``_face_root``, ``_clamp_to_domain``, ``_descend``, then the
patch's basis:
``_box_spline_first``, ``_quartic_bezier_first``, ``_triangle_second`` or ``_quad_patch``); Warp inlines them, so
the kernel runs the same operations in the same order as one body would.

The quartic-triangle functions below (``_bern4``, ``_bern4_grad``, ``_bern4_hessian``, ``_box12``, ``_loop_box``)
are written out with constant indices only (the derivatives place the degree-3 and degree-2 values of
``_bern3_times4`` and ``_bern2_times12`` at the quartic exponents they belong to), so that Warp keeps their values
in registers; they were generated from ``TRI_BEZIER_INDEX`` and ``LOOP_BEZIER`` (tests/test_limit_surface.py checks
the evaluated patches against the box spline derived from Loop's stencils). Points and first derivatives of a
box-spline patch take ``_loop_box``: the basis and its two derivatives from the ten cubic monomials of (1 - s - t,
s, t) with integer weights (about half the operations of the quartic Bernstein values, their gradients and three
``_box12`` products, which end caps and second derivatives still use).
"""
import warp as wp

wp.set_module_options({"enable_backward": False})

#: face kinds of the parameterisation (warp_subdiv.limit's DIRECT = 0, SUBFACES, FAN)
SUBFACES = wp.constant(1)
FAN = wp.constant(2)
#: leaf markers (warp_subdiv.limit.patches.SPLIT / HOLE)
SPLIT = wp.constant(-1)
HOLE = wp.constant(-2)


vec6d = wp.types.vector(length=6, dtype=wp.float64)
vec10d = wp.types.vector(length=10, dtype=wp.float64)
vec12d = wp.types.vector(length=12, dtype=wp.float64)
vec15d = wp.types.vector(length=15, dtype=wp.float64)


@wp.func
def _cubic_basis(t: wp.float64, bspline: int):
    """Values, first and second derivatives of the four cubic basis functions at t: uniform B-spline or
    Bernstein."""
    one = wp.float64(1.0)
    three = wp.float64(3.0)
    six = wp.float64(6.0)
    s = one - t
    if bspline != 0:
        sixth = one / six
        b = wp.vec4d(s * s * s * sixth, (three * t * t * t - six * t * t + wp.float64(4.0)) * sixth,
                     (-three * t * t * t + three * t * t + three * t + one) * sixth, t * t * t * sixth)
        d = wp.vec4d(-s * s * wp.float64(0.5), (three * t * t - wp.float64(4.0) * t) * wp.float64(0.5),
                     (-three * t * t + wp.float64(2.0) * t + one) * wp.float64(0.5), t * t * wp.float64(0.5))
        dd = wp.vec4d(s, three * t - wp.float64(2.0), one - three * t, t)
        return b, d, dd
    b = wp.vec4d(s * s * s, three * t * s * s, three * t * t * s, t * t * t)
    d = wp.vec4d(-three * s * s, three * s * s - six * t * s, six * t * s - three * t * t, three * t * t)
    dd = wp.vec4d(six * s, wp.float64(18.0) * t - wp.float64(12.0), six - wp.float64(18.0) * t, six * t)
    return b, d, dd


# -- quartic triangles (generated; see the module docstring) ------------------------------------------------
@wp.func
def _bern4(w0: wp.float64, w1: wp.float64, w2: wp.float64) -> vec15d:
    """The 15 quartic Bernstein polynomials, in TRI_BEZIER_INDEX order (generated)."""
    return vec15d(
        w0*w0*w0*w0,
        wp.float64(4.0) * w0*w0*w0 * w1,
        wp.float64(4.0) * w0*w0*w0 * w2,
        wp.float64(6.0) * w0*w0 * w1*w1,
        wp.float64(12.0) * w0*w0 * w1 * w2,
        wp.float64(6.0) * w0*w0 * w2*w2,
        wp.float64(4.0) * w0 * w1*w1*w1,
        wp.float64(12.0) * w0 * w1*w1 * w2,
        wp.float64(12.0) * w0 * w1 * w2*w2,
        wp.float64(4.0) * w0 * w2*w2*w2,
        w1*w1*w1*w1,
        wp.float64(4.0) * w1*w1*w1 * w2,
        wp.float64(6.0) * w1*w1 * w2*w2,
        wp.float64(4.0) * w1 * w2*w2*w2,
        w2*w2*w2*w2)


@wp.func
def _bern3_times4(w0: wp.float64, w1: wp.float64, w2: wp.float64) -> vec10d:
    """4 times the 10 cubic Bernstein polynomials of (w0, w1, w2), exponents in the order of TRI_BEZIER_INDEX's
    degree-3 analogue (generated)."""
    four = wp.float64(4.0)
    return vec10d(
        four * w0*w0*w0,
        four * wp.float64(3.0) * w0*w0 * w1,
        four * wp.float64(3.0) * w0*w0 * w2,
        four * wp.float64(3.0) * w0 * w1*w1,
        four * wp.float64(6.0) * w0 * w1 * w2,
        four * wp.float64(3.0) * w0 * w2*w2,
        four * w1*w1*w1,
        four * wp.float64(3.0) * w1*w1 * w2,
        four * wp.float64(3.0) * w1 * w2*w2,
        four * w2*w2*w2)


@wp.func
def _bern4_grad(w0: wp.float64, w1: wp.float64, w2: wp.float64, i: int) -> vec15d:
    """d/dw_i of the 15 quartic Bernstein polynomials: 4 B3_(e - e_i), the cubic value of exponent e - e_i placed
    at quartic exponent e (zero where e has no e_i)."""
    c = _bern3_times4(w0, w1, w2)
    z = wp.float64(0.0)
    if i == 0:
        return vec15d(c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], z, z, z, z, z)
    elif i == 1:
        return vec15d(z, c[0], z, c[1], c[2], z, c[3], c[4], c[5], z, c[6], c[7], c[8], c[9], z)
    else:
        return vec15d(z, z, c[0], z, c[1], c[2], z, c[3], c[4], c[5], z, c[6], c[7], c[8], c[9])
    return vec15d()


@wp.func
def _bern2_times12(w0: wp.float64, w1: wp.float64, w2: wp.float64) -> vec6d:
    """12 times the 6 quadratic Bernstein polynomials of (w0, w1, w2), exponents (2,0,0), (1,1,0), (1,0,1),
    (0,2,0), (0,1,1), (0,0,2) (generated)."""
    twelve = wp.float64(12.0)
    return vec6d(
        twelve * w0*w0,
        twelve * wp.float64(2.0) * w0 * w1,
        twelve * wp.float64(2.0) * w0 * w2,
        twelve * w1*w1,
        twelve * wp.float64(2.0) * w1 * w2,
        twelve * w2*w2)


@wp.func
def _bern4_hessian(w0: wp.float64, w1: wp.float64, w2: wp.float64, i: int, j: int) -> vec15d:
    """d2/dw_i dw_j of the 15 quartic Bernstein polynomials: 12 B2_(e - e_i - e_j), the quadratic value of
    exponent e - e_i - e_j placed at quartic exponent e (zero elsewhere)."""
    q = _bern2_times12(w0, w1, w2)
    z = wp.float64(0.0)
    if i == 0 and j == 0:
        return vec15d(q[0], q[1], q[2], q[3], q[4], q[5], z, z, z, z, z, z, z, z, z)
    elif i == 0 and j == 1:
        return vec15d(z, q[0], z, q[1], q[2], z, q[3], q[4], q[5], z, z, z, z, z, z)
    elif i == 0 and j == 2:
        return vec15d(z, z, q[0], z, q[1], q[2], z, q[3], q[4], q[5], z, z, z, z, z)
    elif i == 1 and j == 1:
        return vec15d(z, z, z, q[0], z, z, q[1], q[2], z, z, q[3], q[4], q[5], z, z)
    elif i == 1 and j == 2:
        return vec15d(z, z, z, z, q[0], z, z, q[1], q[2], z, z, q[3], q[4], q[5], z)
    elif i == 2 and j == 2:
        return vec15d(z, z, z, z, z, q[0], z, z, q[1], q[2], z, z, q[3], q[4], q[5])
    return vec15d()


@wp.func
def _box12(b: vec15d) -> vec12d:
    """The 12 quartic box-spline basis values (TRI_RING order) from Bernstein values: LOOP_BEZIER^T b
    (generated from warp_subdiv.limit.bezier.LOOP_BEZIER, entries in 24ths)."""
    s = wp.float64(1.0) / wp.float64(24.0)
    return vec12d(
        s * (wp.float64(12.0) * b[0] + wp.float64(12.0) * b[1] + wp.float64(12.0) * b[2] + wp.float64(8.0) * b[3]
             + wp.float64(10.0) * b[4] + wp.float64(8.0) * b[5] + wp.float64(4.0) * b[6] + wp.float64(6.0) * b[7]
             + wp.float64(6.0) * b[8] + wp.float64(4.0) * b[9] + wp.float64(2.0) * b[10] + wp.float64(3.0) * b[11]
             + wp.float64(4.0) * b[12] + wp.float64(3.0) * b[13] + wp.float64(2.0) * b[14]),
        s * (wp.float64(2.0) * b[0] + wp.float64(4.0) * b[1] + wp.float64(3.0) * b[2] + wp.float64(8.0) * b[3]
             + wp.float64(6.0) * b[4] + wp.float64(4.0) * b[5] + wp.float64(12.0) * b[6] + wp.float64(10.0) * b[7]
             + wp.float64(6.0) * b[8] + wp.float64(3.0) * b[9] + wp.float64(12.0) * b[10] + wp.float64(12.0) * b[11]
             + wp.float64(8.0) * b[12] + wp.float64(4.0) * b[13] + wp.float64(2.0) * b[14]),
        s * (wp.float64(2.0) * b[0] + wp.float64(3.0) * b[1] + wp.float64(4.0) * b[2] + wp.float64(4.0) * b[3]
             + wp.float64(6.0) * b[4] + wp.float64(8.0) * b[5] + wp.float64(3.0) * b[6] + wp.float64(6.0) * b[7]
             + wp.float64(10.0) * b[8] + wp.float64(12.0) * b[9] + wp.float64(2.0) * b[10] + wp.float64(4.0) * b[11]
             + wp.float64(8.0) * b[12] + wp.float64(12.0) * b[13] + wp.float64(12.0) * b[14]),
        s * (wp.float64(2.0) * b[0] + b[1] + wp.float64(3.0) * b[2] + b[4]
             + wp.float64(4.0) * b[5] + b[8] + wp.float64(3.0) * b[9] + b[13]
             + wp.float64(2.0) * b[14]),
        s * (wp.float64(2.0) * b[0] + b[2]),
        s * (wp.float64(2.0) * b[0] + b[1]),
        s * (wp.float64(2.0) * b[0] + wp.float64(3.0) * b[1] + b[2] + wp.float64(4.0) * b[3]
             + b[4] + wp.float64(3.0) * b[6] + b[7] + wp.float64(2.0) * b[10]
             + b[11]),
        s * (wp.float64(2.0) * b[10] + b[11]),
        s * (b[6] + b[7] + b[8] + b[9]
             + wp.float64(2.0) * b[10] + wp.float64(3.0) * b[11] + wp.float64(4.0) * b[12] + wp.float64(3.0) * b[13]
             + wp.float64(2.0) * b[14]),
        s * (b[6] + wp.float64(2.0) * b[10]),
        s * (b[13] + wp.float64(2.0) * b[14]),
        s * (b[9] + wp.float64(2.0) * b[14]))


@wp.func
def _loop_box(s: wp.float64, t: wp.float64):
    """The 12 quartic box-spline basis functions (TRI_RING order) at (s, t) and their s and t derivatives, each
    scaled to integer weights: (24 b, 6 db/ds, 6 db/dt) (generated from LOOP_BEZIER: with (w0, w1, w2) =
    (1 - s - t, s, t) and the cubic Bernstein polynomials B3, b = (1/24) sum_i w_i A_i^T B3 and db/ds =
    (1/6) (A_1 - A_0)^T B3, where A_i[k, j] = 24 LOOP_BEZIER[k + e_i, j]; so 24 b = A_0^T B3 + 4 s db/ds + 4 t
    db/dt). The multinomial coefficients are folded into the integer weights of the monomials."""
    zero = wp.float64(0.0)
    w0 = wp.float64(1.0) - s - t
    mw03 = w0 * w0 * w0
    mw02_s = w0 * w0 * s
    mw02_t = w0 * w0 * t
    mw0_s2 = w0 * s * s
    mw0_s_t = w0 * s * t
    mw0_t2 = w0 * t * t
    ms3 = s * s * s
    ms2_t = s * s * t
    ms_t2 = s * t * t
    mt3 = t * t * t
    gs = vec12d(
        -wp.float64(12.0) * mw02_s - wp.float64(6.0) * mw02_t - wp.float64(12.0) * mw0_s2
            - wp.float64(24.0) * mw0_s_t - wp.float64(6.0) * mw0_t2 - wp.float64(2.0) * ms3
            - wp.float64(9.0) * ms2_t - wp.float64(6.0) * ms_t2 - mt3,
        wp.float64(2.0) * mw03 + wp.float64(12.0) * mw02_s + wp.float64(9.0) * mw02_t
            + wp.float64(12.0) * mw0_s2 + wp.float64(24.0) * mw0_s_t + wp.float64(6.0) * mw0_t2
            + wp.float64(6.0) * ms2_t + wp.float64(6.0) * ms_t2 + mt3,
        mw03 + wp.float64(3.0) * mw02_s + wp.float64(6.0) * mw02_t - wp.float64(3.0) * mw0_s2
            + wp.float64(6.0) * mw0_t2 - ms3 - wp.float64(6.0) * ms2_t - wp.float64(6.0) * ms_t2,
        -mw03 - wp.float64(3.0) * mw02_s - wp.float64(6.0) * mw02_t - wp.float64(6.0) * mw0_s_t
            - wp.float64(9.0) * mw0_t2 - wp.float64(3.0) * ms_t2 - wp.float64(2.0) * mt3,
        -wp.float64(2.0) * mw03 - wp.float64(3.0) * mw02_t,
        -mw03 - wp.float64(3.0) * mw02_s,
        mw03 + wp.float64(3.0) * mw02_s - wp.float64(3.0) * mw0_s2 - ms3,
        wp.float64(2.0) * ms3 + wp.float64(3.0) * ms2_t,
        wp.float64(3.0) * mw0_s2 + wp.float64(6.0) * mw0_s_t + wp.float64(3.0) * mw0_t2 + ms3
            + wp.float64(6.0) * ms2_t + wp.float64(9.0) * ms_t2 + wp.float64(2.0) * mt3,
        wp.float64(3.0) * mw0_s2 + ms3,
        mt3,
        -mt3)
    gt = vec12d(
        -wp.float64(6.0) * mw02_s - wp.float64(12.0) * mw02_t - wp.float64(6.0) * mw0_s2
            - wp.float64(24.0) * mw0_s_t - wp.float64(12.0) * mw0_t2 - ms3 - wp.float64(6.0) * ms2_t
            - wp.float64(9.0) * ms_t2 - wp.float64(2.0) * mt3,
        mw03 + wp.float64(6.0) * mw02_s + wp.float64(3.0) * mw02_t + wp.float64(6.0) * mw0_s2
            - wp.float64(3.0) * mw0_t2 - wp.float64(6.0) * ms2_t - wp.float64(6.0) * ms_t2 - mt3,
        wp.float64(2.0) * mw03 + wp.float64(9.0) * mw02_s + wp.float64(12.0) * mw02_t
            + wp.float64(6.0) * mw0_s2 + wp.float64(24.0) * mw0_s_t + wp.float64(12.0) * mw0_t2 + ms3
            + wp.float64(6.0) * ms2_t + wp.float64(6.0) * ms_t2,
        mw03 + wp.float64(3.0) * mw02_t - wp.float64(3.0) * mw0_t2 - mt3,
        -mw03 - wp.float64(3.0) * mw02_t,
        -wp.float64(2.0) * mw03 - wp.float64(3.0) * mw02_s,
        -mw03 - wp.float64(6.0) * mw02_s - wp.float64(3.0) * mw02_t - wp.float64(9.0) * mw0_s2
            - wp.float64(6.0) * mw0_s_t - wp.float64(2.0) * ms3 - wp.float64(3.0) * ms2_t,
        ms3,
        wp.float64(3.0) * mw0_s2 + wp.float64(6.0) * mw0_s_t + wp.float64(3.0) * mw0_t2
            + wp.float64(2.0) * ms3 + wp.float64(9.0) * ms2_t + wp.float64(6.0) * ms_t2 + mt3,
        -ms3,
        wp.float64(3.0) * ms_t2 + wp.float64(2.0) * mt3,
        wp.float64(3.0) * mw0_t2 + mt3)
    g0 = vec12d(
        wp.float64(12.0) * mw03 + wp.float64(36.0) * mw02_s + wp.float64(36.0) * mw02_t
            + wp.float64(24.0) * mw0_s2 + wp.float64(60.0) * mw0_s_t + wp.float64(24.0) * mw0_t2
            + wp.float64(4.0) * ms3 + wp.float64(18.0) * ms2_t + wp.float64(18.0) * ms_t2
            + wp.float64(4.0) * mt3,
        wp.float64(2.0) * mw03 + wp.float64(12.0) * mw02_s + wp.float64(9.0) * mw02_t
            + wp.float64(24.0) * mw0_s2 + wp.float64(36.0) * mw0_s_t + wp.float64(12.0) * mw0_t2
            + wp.float64(12.0) * ms3 + wp.float64(30.0) * ms2_t + wp.float64(18.0) * ms_t2
            + wp.float64(3.0) * mt3,
        wp.float64(2.0) * mw03 + wp.float64(9.0) * mw02_s + wp.float64(12.0) * mw02_t
            + wp.float64(12.0) * mw0_s2 + wp.float64(36.0) * mw0_s_t + wp.float64(24.0) * mw0_t2
            + wp.float64(3.0) * ms3 + wp.float64(18.0) * ms2_t + wp.float64(30.0) * ms_t2
            + wp.float64(12.0) * mt3,
        wp.float64(2.0) * mw03 + wp.float64(3.0) * mw02_s + wp.float64(9.0) * mw02_t
            + wp.float64(6.0) * mw0_s_t + wp.float64(12.0) * mw0_t2 + wp.float64(3.0) * ms_t2
            + wp.float64(3.0) * mt3,
        wp.float64(2.0) * mw03 + wp.float64(3.0) * mw02_t,
        wp.float64(2.0) * mw03 + wp.float64(3.0) * mw02_s,
        wp.float64(2.0) * mw03 + wp.float64(9.0) * mw02_s + wp.float64(3.0) * mw02_t
            + wp.float64(12.0) * mw0_s2 + wp.float64(6.0) * mw0_s_t + wp.float64(3.0) * ms3
            + wp.float64(3.0) * ms2_t,
        zero,
        ms3 + wp.float64(3.0) * ms2_t + wp.float64(3.0) * ms_t2 + mt3,
        ms3,
        zero,
        mt3)
    return g0 + s * gs + t * gt, gs, gt


# -- the steps of one evaluation ---------------------------------------------------------------------------
@wp.func
def _face_root(info: wp.vec4i, u: wp.float64, v: wp.float64):
    """The root node of the patch tree under a base face's (u, v) and the root's own (s, t), with the scales
    (js, jt) of d(s, t)/d(u, v): the face itself, a Catmull-Clark n-gon's sub-face tile or a Loop polygon's fan
    triangle. ``info``: (kind, first root node, size * 256 + tiles, ...) of the face."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    kind = info[0]
    node = info[1]
    size = info[2] >> 8
    s = u
    t = v
    js = one
    jt = one
    if kind == SUBFACES:  # Catmull-Clark n-gon: sub-face tiles of half-unit squares (Bfr's QUAD_SUBFACES)
        tu = wp.floor(u)
        tv = wp.floor(v)
        if u - tu > wp.float64(0.75):
            tu = tu + one
        if v - tv > wp.float64(0.75):
            tv = tv + one
        w = info[2] & 255
        sub = wp.clamp(int(tv) * w + int(tu), 0, size - 1)
        tu = wp.float64(sub % w)
        tv = wp.float64(sub // w)
        node = node + sub
        s = two * (u - tu)
        t = two * (v - tv)
        js = two
        jt = two
    elif kind == FAN:  # Loop polygon: fan triangle k on the half-unit tile at (k, 0), as Bfr's sub-face tiles
        tu = wp.floor(u)
        if u - tu > wp.float64(0.75):
            tu = tu + one
        k = wp.clamp(int(tu), 0, size - 3)
        node = node + k
        s = two * (u - wp.float64(k))
        t = two * v
        js = two
        jt = two
    return node, s, t, js, jt


@wp.func
def _clamp_to_domain(s: wp.float64, t: wp.float64, triangles: int):
    """(s, t) moved onto the root's domain: the unit square, or the unit triangle (scaled toward the origin)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    s = wp.clamp(s, zero, one)
    t = wp.clamp(t, zero, one)
    if triangles != 0 and s + t > one:
        total = s + t
        s = s / total
        t = t / total
    return s, t


@wp.func
def _descend(node_child: wp.array2d(dtype=wp.int32), node_patch: wp.array(dtype=wp.int32), node: int, patch: int,
             s: wp.float64, t: wp.float64, js: wp.float64, jt: wp.float64, triangles: int):
    """From a split node down to the leaf holding (s, t): (leaf's patch, its (s, t), the scales (js, jt) of
    d(s, t)/d(u, v)). Quadrants, or a triangle's corner children and its middle child (frame turned by 180
    degrees: the scales change sign); every level doubles the scales."""
    one = wp.float64(1.0)
    half = wp.float64(0.5)
    two = wp.float64(2.0)
    while patch == SPLIT:
        slot = int(0)
        if triangles != 0:
            if s >= half:
                slot = 1
                s = two * s - one
                t = two * t
            elif t >= half:
                slot = 2
                s = two * s
                t = two * t - one
            elif s + t <= half:
                s = two * s
                t = two * t
            else:
                slot = 3
                s = one - two * s
                t = one - two * t
                js = -js
                jt = -jt
        else:
            bu = int(0)
            bv = int(0)
            if s >= half:
                bu = 1
                s = two * s - one
            else:
                s = two * s
            if t >= half:
                bv = 1
                t = two * t - one
            else:
                t = two * t
            slot = bu
            if bv != 0:
                slot = 3 - bu
        js = two * js
        jt = two * jt
        node = node_child[node, slot]
        patch = node_patch[node]
    return patch, s, t, js, jt


@wp.func
def _box_spline_first(points: wp.array(dtype=wp.vec3d), patch_index: wp.array2d(dtype=wp.int32), patch: int,
                      s: wp.float64, t: wp.float64):
    """Point and (s, t) derivatives of a box-spline patch (12 indexed points): integer weights of the monomials
    (_loop_box), the scale applied once to the sums."""
    p = wp.vec3d()
    ds = wp.vec3d()
    dt = wp.vec3d()
    wv, wvs, wvt = _loop_box(s, t)
    for j in range(12):
        cp = points[patch_index[patch, j]]
        p += wv[j] * cp
        ds += wvs[j] * cp
        dt += wvt[j] * cp
    p = p / wp.float64(24.0)
    ds = ds / wp.float64(6.0)
    dt = dt / wp.float64(6.0)
    return p, ds, dt


@wp.func
def _quartic_bezier_first(points: wp.array(dtype=wp.vec3d), base: int, w0: wp.float64, s: wp.float64,
                          t: wp.float64):
    """Point and (s, t) derivatives of a quartic triangular Bezier patch (15 consecutive points from ``base``):
    the Bernstein values and their hodograph."""
    p = wp.vec3d()
    ds = wp.vec3d()
    dt = wp.vec3d()
    bern = _bern4(w0, s, t)
    g0 = _bern4_grad(w0, s, t, 0)
    bern_s = _bern4_grad(w0, s, t, 1) - g0
    bern_t = _bern4_grad(w0, s, t, 2) - g0
    for j in range(15):
        cp = points[base + j]
        p += bern[j] * cp
        ds += bern_s[j] * cp
        dt += bern_t[j] * cp
    return p, ds, dt


@wp.func
def _triangle_second(points: wp.array(dtype=wp.vec3d), patch_index: wp.array2d(dtype=wp.int32), patch: int,
                     box: bool, w0: wp.float64, s: wp.float64, t: wp.float64):
    """Second (s, t) derivatives of a triangle patch from the Bernstein Hessians (a box spline's weighed with
    LOOP_BEZIER^T through _box12)."""
    two = wp.float64(2.0)
    dss = wp.vec3d()
    dst = wp.vec3d()
    dtt = wp.vec3d()
    h00 = _bern4_hessian(w0, s, t, 0, 0)
    h01 = _bern4_hessian(w0, s, t, 0, 1)
    h02 = _bern4_hessian(w0, s, t, 0, 2)
    bern_ss = _bern4_hessian(w0, s, t, 1, 1) - two * h01 + h00
    bern_st = _bern4_hessian(w0, s, t, 1, 2) - h02 - h01 + h00
    bern_tt = _bern4_hessian(w0, s, t, 2, 2) - two * h02 + h00
    if box:
        wss = _box12(bern_ss)
        wst = _box12(bern_st)
        wtt = _box12(bern_tt)
        for j in range(12):
            cp = points[patch_index[patch, j]]
            dss += wss[j] * cp
            dst += wst[j] * cp
            dtt += wtt[j] * cp
    else:
        base = patch_index[patch, 0]
        for j in range(15):
            cp = points[base + j]
            dss += bern_ss[j] * cp
            dst += bern_st[j] * cp
            dtt += bern_tt[j] * cp
    return dss, dst, dtt


@wp.func
def _quad_patch(points: wp.array(dtype=wp.vec3d), patch_index: wp.array2d(dtype=wp.int32), patch: int,
                bezier: int, s: wp.float64, t: wp.float64, second: int):
    """Point, first and (with ``second``) second (s, t) derivatives of a bicubic patch (16 indexed points,
    uniform B-spline or Bezier), as sums over rows of the tensor product."""
    p = wp.vec3d()
    ds = wp.vec3d()
    dt = wp.vec3d()
    dss = wp.vec3d()
    dst = wp.vec3d()
    dtt = wp.vec3d()
    bspline = 1 - bezier
    bs, ds1, ds2 = _cubic_basis(s, bspline)
    bt, dt1, dt2 = _cubic_basis(t, bspline)
    if second != 0:
        for b in range(4):
            r0 = wp.vec3d()
            r1 = wp.vec3d()
            r2 = wp.vec3d()
            for a in range(4):
                cp = points[patch_index[patch, a + 4 * b]]
                r0 += bs[a] * cp
                r1 += ds1[a] * cp
                r2 += ds2[a] * cp
            p += bt[b] * r0
            ds += bt[b] * r1
            dt += dt1[b] * r0
            dss += bt[b] * r2
            dst += dt1[b] * r1
            dtt += dt2[b] * r0
    else:
        for b in range(4):
            r0 = wp.vec3d()
            r1 = wp.vec3d()
            for a in range(4):
                cp = points[patch_index[patch, a + 4 * b]]
                r0 += bs[a] * cp
                r1 += ds1[a] * cp
            p += bt[b] * r0
            ds += bt[b] * r1
            dt += dt1[b] * r0
    return p, ds, dt, dss, dst, dtt


@wp.kernel
def limit_evaluate(
    face_info: wp.array(dtype=wp.vec4i),
    query_face: wp.array(dtype=wp.int32),
    query_u: wp.array(dtype=wp.float64),
    query_v: wp.array(dtype=wp.float64),
    node_child: wp.array2d(dtype=wp.int32),
    node_patch: wp.array(dtype=wp.int32),
    patch_index: wp.array2d(dtype=wp.int32),
    patch_basis: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3d),
    patch_exact: wp.array(dtype=wp.int32),
    exact: int,
    triangles: int,
    second: int,
    out_p: wp.array(dtype=wp.vec3d),
    out_du: wp.array(dtype=wp.vec3d),
    out_dv: wp.array(dtype=wp.vec3d),
    out_duu: wp.array(dtype=wp.vec3d),
    out_duv: wp.array(dtype=wp.vec3d),
    out_dvv: wp.array(dtype=wp.vec3d),
    out_n: wp.array(dtype=wp.vec3d),
    out_patch: wp.array(dtype=wp.int32),
    out_local: wp.array(dtype=wp.vec4d),
):
    i = wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    # (kind, root node, size * 256 + tiles, 2 * patch + Bezier of a one-patch face or -1)
    info = face_info[query_face[i]]
    node, s, t, js, jt = _face_root(info, query_u[i], query_v[i])
    s, t = _clamp_to_domain(s, t, triangles)
    leaf = info[3]
    patch = int(0)
    bezier = int(0)
    if leaf >= 0:  # a face that is one patch: no node or basis lookups
        patch = leaf >> 1
        bezier = leaf & 1
    else:
        patch = node_patch[node]
    patch, s, t, js, jt = _descend(node_child, node_patch, node, patch, s, t, js, jt, triangles)
    if leaf < 0 and patch >= 0:
        bezier = patch_basis[patch]
    out_patch[i] = patch
    if exact != 0 and patch >= 0:
        if patch_exact[patch] >= 0:  # a patch evaluated again on the host: its own (s, t) and the scales
            out_local[i] = wp.vec4d(s, t, js, jt)
    if patch == HOLE:
        nan = wp.float64(wp.nan)
        q = wp.vec3d(nan, nan, nan)
        out_p[i] = q
        out_du[i] = q
        out_dv[i] = q
        out_n[i] = q
        return
    p = wp.vec3d()
    ds = wp.vec3d()
    dt = wp.vec3d()
    dss = wp.vec3d()
    dst = wp.vec3d()
    dtt = wp.vec3d()
    if triangles != 0:
        # quartic Bernstein polynomials of (w0, w1, w2) = (1 - s - t, s, t) and their derivatives (hodograph);
        # a box-spline patch (12 indexed points) weighs them with LOOP_BEZIER^T, an end cap (15 consecutive Bezier
        # points) directly
        box = bezier == 0
        w0 = one - s - t
        if box:
            p, ds, dt = _box_spline_first(points, patch_index, patch, s, t)
        else:
            p, ds, dt = _quartic_bezier_first(points, patch_index[patch, 0], w0, s, t)
        if second != 0:
            dss, dst, dtt = _triangle_second(points, patch_index, patch, box, w0, s, t)
    else:
        p, ds, dt, dss, dst, dtt = _quad_patch(points, patch_index, patch, bezier, s, t, second)
    du = js * ds
    dv = jt * dt
    out_p[i] = p
    out_du[i] = du
    out_dv[i] = dv
    if second != 0:
        out_duu[i] = (js * js) * dss
        out_duv[i] = (js * jt) * dst
        out_dvv[i] = (jt * jt) * dtt
    n = wp.cross(du, dv)
    length = wp.length(n)
    if length > zero:
        n = n / length
    out_n[i] = n
