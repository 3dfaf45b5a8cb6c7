"""Limit-surface evaluation kernel (:class:`warp_subdiv.limit.LimitSurface`), float64.

One thread per query point: map the base face's (u, v) onto a root of the patch tree (the face itself; a
Catmull-Clark n-gon's sub-face tile; a Loop polygon's fan triangle), descend the tree (quadrants, or a
triangle's corner and middle children) to a leaf, and evaluate its Bezier patch: bicubic (16 control points,
index a + 4 b for the Bernstein polynomials B_a(s) B_b(t)) or quartic triangular (15 control points, exponents of
(1 - s - t, s, t) in the order of ``warp_subdiv.limit_patches.TRI_BEZIER_INDEX``). Derivatives are returned
with respect to the base face's (u, v): the descent's scale (2 per level; -2 in a triangle's middle child,
whose frame is turned by 180 degrees) is applied on the way out. Kernels know nothing about subdivision rules.
"""
import warp as wp

wp.set_module_options({"enable_backward": False, "max_unroll": 1})

#: face kinds of the parameterisation
DIRECT, SUBFACES, FAN = 0, 1, 2
#: leaf markers (warp_subdiv.limit_patches.SPLIT / HOLE)
SPLIT = wp.constant(-1)
HOLE = wp.constant(-2)


vec5d = wp.types.vector(length=5, dtype=wp.float64)


@wp.func
def _fact(k: int) -> wp.float64:
    r = wp.float64(1.0)
    for i in range(2, k + 1):
        r = r * wp.float64(i)
    return r


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


@wp.func
def _mono(pw0: vec5d, pw1: vec5d, pw2: vec5d, a: int, b: int, c: int) -> wp.float64:
    """w0^a w1^b w2^c from the powers of the barycentric coordinates, 0 where an exponent is negative."""
    if a < 0 or b < 0 or c < 0:
        return wp.float64(0.0)
    return pw0[a] * pw1[b] * pw2[c]


@wp.kernel
def limit_evaluate(
    face_kind: wp.array(dtype=wp.int32),
    face_root: wp.array(dtype=wp.int32),
    face_size: wp.array(dtype=wp.int32),
    face_tiles: wp.array(dtype=wp.int32),
    query_face: wp.array(dtype=wp.int32),
    query_u: wp.array(dtype=wp.float64),
    query_v: wp.array(dtype=wp.float64),
    node_child: wp.array2d(dtype=wp.int32),
    node_patch: wp.array(dtype=wp.int32),
    patch_index: wp.array2d(dtype=wp.int32),
    patch_basis: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3d),
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
):
    i = wp.tid()
    f = query_face[i]
    u = query_u[i]
    v = query_v[i]
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    half = wp.float64(0.5)
    two = wp.float64(2.0)
    kind = face_kind[f]
    node = face_root[f]
    s = u
    t = v
    js = one
    jt = one
    if kind == 1:  # Catmull-Clark n-gon: sub-face tiles of half-unit squares (Bfr's QUAD_SUBFACES)
        tu = wp.floor(u)
        tv = wp.floor(v)
        if u - tu > wp.float64(0.75):
            tu = tu + one
        if v - tv > wp.float64(0.75):
            tv = tv + one
        w = face_tiles[f]
        sub = wp.clamp(int(tv) * w + int(tu), 0, face_size[f] - 1)
        tu = wp.float64(sub % w)
        tv = wp.float64(sub // w)
        node = node + sub
        s = two * (u - tu)
        t = two * (v - tv)
        js = two
        jt = two
    elif kind == 2:  # Loop polygon: fan triangle k on the half-unit tile at (k, 0), as Bfr's sub-face tiles
        tu = wp.floor(u)
        if u - tu > wp.float64(0.75):
            tu = tu + one
        k = wp.clamp(int(tu), 0, face_size[f] - 3)
        node = node + k
        s = two * (u - wp.float64(k))
        t = two * v
        js = two
        jt = two
    s = wp.clamp(s, zero, one)
    t = wp.clamp(t, zero, one)
    if triangles != 0 and s + t > one:
        total = s + t
        s = s / total
        t = t / total
    patch = node_patch[node]
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
    out_patch[i] = patch
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
        # powers 0..4 of the barycentric coordinates; monomial w0^a w1^b w2^c, exponents below 0 give 0
        w0 = one - s - t
        pw0 = vec5d(one, w0, w0 * w0, w0 * w0 * w0, w0 * w0 * w0 * w0)
        pw1 = vec5d(one, s, s * s, s * s * s, s * s * s * s)
        pw2 = vec5d(one, t, t * t, t * t * t, t * t * t * t)
        k = int(0)
        for a in range(4, -1, -1):
            for b in range(4 - a, -1, -1):
                c = 4 - a - b
                cp = points[patch_index[patch, k]]
                coef = wp.float64(24.0) / (_fact(a) * _fact(b) * _fact(c))
                p += (coef * _mono(pw0, pw1, pw2, a, b, c)) * cp
                d0 = wp.float64(a) * _mono(pw0, pw1, pw2, a - 1, b, c)
                d1 = wp.float64(b) * _mono(pw0, pw1, pw2, a, b - 1, c)
                d2 = wp.float64(c) * _mono(pw0, pw1, pw2, a, b, c - 1)
                ds += (coef * (d1 - d0)) * cp
                dt += (coef * (d2 - d0)) * cp
                if second != 0:
                    d00 = wp.float64(a * (a - 1)) * _mono(pw0, pw1, pw2, a - 2, b, c)
                    d11 = wp.float64(b * (b - 1)) * _mono(pw0, pw1, pw2, a, b - 2, c)
                    d22 = wp.float64(c * (c - 1)) * _mono(pw0, pw1, pw2, a, b, c - 2)
                    d01 = wp.float64(a * b) * _mono(pw0, pw1, pw2, a - 1, b - 1, c)
                    d02 = wp.float64(a * c) * _mono(pw0, pw1, pw2, a - 1, b, c - 1)
                    d12 = wp.float64(b * c) * _mono(pw0, pw1, pw2, a, b - 1, c - 1)
                    dss += (coef * (d11 - two * d01 + d00)) * cp
                    dst += (coef * (d12 - d02 - d01 + d00)) * cp
                    dtt += (coef * (d22 - two * d02 + d00)) * cp
                k = k + 1
    else:
        bspline = int(0)
        if patch_basis[patch] == 0:
            bspline = 1
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
