"""Eigenvectors, limit masks and flatness parameters (docs/rules.md sections 6 to 9) as pure functions.

Every function is vectorised over a group of neighbourhoods with the same size: ``k`` is one integer,
``theta`` and ``s`` are arrays of shape (S,), and the result has shape (S, n) over the local vector

* Loop interior ``[c, p_0..p_{k-1}]``, Catmull-Clark interior ``[c, p_0..p_{k-1}, q_0..q_{k-1}]``;
* Loop sector ``[c, p_0..p_k]``, Catmull-Clark sector ``[c, p_0..p_k, q_0..q_{k-1}]``,

with the ring listed counter-clockwise around the outward normal. ``l0`` is the limit-position mask,
``l1``/``l2`` the tangent masks, ``x1``/``x2`` the right eigenvectors with ``l^i . x^j = delta_ij``, and
``tu``/``tv`` the two tangent masks in the order whose cross product points outward (docs/rules.md section 9).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .weights import (
    CATMULL_CLARK,
    LOOP,
    SECTOR_CONCAVE,
    SECTOR_CONVEX,
    SECTOR_CREASE,
    SECTOR_STRAIGHT,
    catmull_clark_interior_vertex_weights,
    gamma,
    loop_beta,
)


@dataclass
class LocalMasks:
    """Masks and eigenvectors of a group of neighbourhoods, each (S, n).

    ``l3``/``x3`` (sector masks only): a third pair of the eigenvalue 1/2, the kink of a straight sector's
    creases (docs/rules.md section 8.7); zero for every other sector, None for rings. The projection of flatness
    and normal control is ``x^0 l^0 + x^1 l^1 + x^2 l^2 + x^3 l^3``."""

    l0: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    tu: np.ndarray
    tv: np.ndarray
    l3: np.ndarray | None = None
    x3: np.ndarray | None = None

    def projector_row(self, r: int) -> np.ndarray:
        """(S, n): row r of P = x^0 l^0 + x^1 l^1 + x^2 l^2 (+ x^3 l^3), i.e. the weights of (P p)_r."""
        row = self.l0 + self.x1[:, r:r + 1] * self.l1 + self.x2[:, r:r + 1] * self.l2
        if self.l3 is not None:
            row = row + self.x3[:, r:r + 1] * self.l3
        return row


def crease_limit_weights():
    """(centre, each of its two crease neighbours) of the limit position of a smooth crease vertex: 2/3, 1/6.

    The cubic B-spline's limit mask: a crease is a B-spline of its own points whatever the faces beside it
    (docs/rules.md sections 8.2 and 8.5), so the same mask serves sector limits and crease vertices without sectors."""
    return 2.0 / 3.0, 1.0 / 6.0


def local_size(scheme: str, k: int, sector: bool) -> int:
    """Length of the local vector."""
    ring = k + 1 if sector else k
    return 1 + ring + (k if scheme == CATMULL_CLARK else 0)


def _col(a):
    return np.asarray(a, dtype=np.float64)[:, None]


def interior_masks(scheme: str, k: int, count: int, beta_variant: str = "loop") -> LocalMasks:
    """Interior (and dart) vertex of valence k (docs/rules.md sections 8.1 and 8.4).

    The masks depend on k only: the (count, n) results are read-only broadcasts of one row (a level's
    interior vertices are most of its vertices; copies would cost 56 bytes per vertex and entry)."""
    n = local_size(scheme, k, sector=False)
    i = np.arange(k)
    tk = np.pi / k
    cos_i, sin_i = np.cos(2 * i * tk), np.sin(2 * i * tk)
    l0, l1, l2, x1, x2 = (np.zeros((1, n)) for _ in range(5))
    if scheme == LOOP:
        beta = float(loop_beta(k, beta_variant))
        denom = 1.0 + 8.0 * k * beta / 3.0
        l0[:, 0] = 1.0 / denom
        l0[:, 1:] = (8.0 * beta / 3.0) / denom
        x1[:, 1:], x2[:, 1:] = cos_i, sin_i
        l1[:, 1:], l2[:, 1:] = (2.0 / k) * cos_i, (2.0 / k) * sin_i
    else:
        lam = (5.0 + np.cos(2 * tk) + np.cos(tk) * np.sqrt(2.0 * (9.0 + np.cos(2 * tk)))) / 16.0
        f = 4.0 * lam - 1.0
        cos_q = np.cos(2 * i * tk) + np.cos(2 * (i + 1) * tk)
        sin_q = np.sin(2 * i * tk) + np.sin(2 * (i + 1) * tk)
        a = 2.0 * f * f / (k * (f * f + np.cos(tk) ** 2))
        l0[:, 0] = k / (k + 5.0)
        l0[:, 1:k + 1] = 4.0 / (k * (k + 5.0))
        l0[:, k + 1:] = 1.0 / (k * (k + 5.0))
        x1[:, 1:k + 1], x1[:, k + 1:] = cos_i, cos_q / f
        x2[:, 1:k + 1], x2[:, k + 1:] = sin_i, sin_q / f
        l1[:, 1:k + 1], l1[:, k + 1:] = a * cos_i, a * cos_q / (4.0 * f)
        l2[:, 1:k + 1], l2[:, k + 1:] = a * sin_i, a * sin_q / (4.0 * f)
    l0, l1, l2, x1, x2 = (np.broadcast_to(m, (count, n)) for m in (l0, l1, l2, x1, x2))
    return LocalMasks(l0, l1, l2, x1, x2, tu=l1, tv=l2)


def sector_masks(scheme: str, kind: np.ndarray, k: int, theta: np.ndarray, flatness=None) -> LocalMasks:
    """Smooth-crease, convex-corner or concave-corner sector with crease degree k.

    docs/rules.md sections 8.2 and 8.5 (smooth creases), 8.3 and 8.6 (corners).

    ``flatness`` (S,) replaces the cross-crease mask of smooth creases by l_cross(s) (docs/rules.md section 6);
    corner masks do not depend on it.
    """
    kind = np.asarray(kind)
    theta = np.asarray(theta, dtype=np.float64)
    count = len(theta)
    n = local_size(scheme, k, sector=True)
    s = np.zeros(count) if flatness is None else np.asarray(flatness, dtype=np.float64)
    crease = kind == SECTOR_CREASE
    corner = ~crease

    corner_l1, corner_l2, corner_x1, corner_x2 = _corner_sector_masks(scheme, k, theta, n)
    l0_crease, cl1, cl2, cx1, cx2 = _crease_sector_masks(scheme, k, s, count, n)
    l0 = np.zeros((count, n))
    l0[corner, 0] = 1.0
    l0[crease] = l0_crease
    l1 = np.where(crease[:, None], cl1, corner_l1)
    l2 = np.where(crease[:, None], cl2, corner_l2)
    x1 = np.where(crease[:, None], cx1, corner_x1)
    x2 = np.where(crease[:, None], cx2, corner_x2)

    # --- orientation (docs/rules.md section 9): normal = tu x tv
    if scheme == LOOP and k >= 2:
        crease_uv = (l1, l2)  # t1 along x t2 across
    else:
        crease_uv = (l2, l1)  # CC: t2 along x t1 across; Loop k = 1: along (l2) x across (l1)
    concave = (kind == SECTOR_CONCAVE)[:, None]
    convex = (kind == SECTOR_CONVEX)[:, None]
    tu = np.where(concave, l1, np.where(convex, l2, crease_uv[0]))
    tv = np.where(concave, l2, np.where(convex, l1, crease_uv[1]))

    # --- straight sectors (docs/rules.md section 8.7): l1/x1 along, l2/x2 across, l3/x3 the kink; tu x tv =
    # along x across points outward, as at a Loop crease
    l3, x3 = np.zeros((count, n)), np.zeros((count, n))
    straight = kind == SECTOR_STRAIGHT
    if np.any(straight):
        v = straight_sector_vectors(scheme, k)
        for dst, src in ((l0, v["l0"]), (l1, v["l1"]), (l2, v["l2"]), (l3, v["l3"]), (x1, v["x1"]),
                         (x2, v["x2"]), (x3, v["x3"]), (tu, v["l1"]), (tv, v["l2"])):
            dst[straight] = src
    return LocalMasks(l0, l1, l2, x1, x2, tu, tv, l3, x3)


def _corner_sector_masks(scheme: str, k: int, theta: np.ndarray, n: int):
    """(l1, l2, x1, x2), each (S, n), of corner sectors of k faces and angles ``theta`` (S,) (docs/rules.md
    sections 8.3 and 8.6): convex and concave share the formulas; theta carries the difference."""
    count = len(theta)
    l1, l2, x1, x2 = (np.zeros((count, n)) for _ in range(4))
    P = slice(1, k + 2)  # p_0..p_k
    Q = slice(k + 2, n)  # q_0..q_{k-1} (Catmull-Clark)
    ip = np.arange(k + 1)
    iq = np.arange(k)
    th = _col(theta)
    skt = np.sin(k * th)
    x1[:, P] = np.sin(ip * th) / skt
    x2[:, P] = np.sin((k - ip) * th) / skt
    if scheme == CATMULL_CLARK:
        x1[:, Q] = (np.sin(iq * th) + np.sin((iq + 1) * th)) / skt
        x2[:, Q] = (np.sin((k - iq) * th) + np.sin((k - iq - 1) * th)) / skt
    l1[:, 0], l1[:, 1 + k] = -1.0, 1.0  # e_{p_k} - e_c
    l2[:, 0], l2[:, 1] = -1.0, 1.0  # e_{p_0} - e_c
    return l1, l2, x1, x2


def _crease_sector_masks(scheme: str, k: int, s, count: int, n: int):
    """(l0 (n,), l1, l2, x1, x2 (count, n)) of smooth crease sectors of k faces with flatness ``s`` ((count,)
    or one value) (docs/rules.md sections 8.2 and 8.5; for k >= 2 the cross-crease mask is l_cross(s),
    section 6)."""
    cl1, cl2, cx1, cx2 = (np.zeros((count, n)) for _ in range(4))
    P = slice(1, k + 2)  # p_0..p_k
    Q = slice(k + 2, n)  # q_0..q_{k-1} (Catmull-Clark)
    ip = np.arange(k + 1)
    iq = np.arange(k)
    tk = np.pi / k
    c_, s_ = np.cos(tk), np.sin(tk)
    l0_crease = np.zeros(n)
    centre_w, neighbour_w = crease_limit_weights()
    l0_crease[0], l0_crease[1], l0_crease[1 + k] = centre_w, neighbour_w, neighbour_w
    if scheme == LOOP:
        if k == 1:  # order [c, p0, p1]: x1/l1 the 1/4 mode (across), x2/l2 along (docs/rules.md section 8.2)
            cx1[:] = [-1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0]
            cl1[:] = [-1.0, 0.5, 0.5]
            cx2[:] = [0.0, 1.0, -1.0]
            cl2[:] = [0.0, 0.5, -0.5]
            cross = 1
        else:  # x1/l1 along, x2/l2 across
            cx1[:, P] = np.cos(ip * tk)
            cl1[:, 1], cl1[:, 1 + k] = 0.5, -0.5
            cx2[:, P] = np.sin(ip * tk)
            cl2[:, 2:1 + k] = (2.0 / k) * np.sin(np.arange(1, k) * tk)
            cl2[:, 0] = -(2.0 / k) * s_
            cl2[:, 1] = cl2[:, 1 + k] = -(1.0 / k) * c_ * (1.0 + c_) / s_
            cross = 2
    else:
        if k == 1:  # order [c, p0, p1, q0]; the 1/4 eigenvalue is defective (docs/rules.md section 8.5)
            cx1[:] = [1.0 / 18.0, -1.0 / 9.0, -1.0 / 9.0, -5.0 / 18.0]
            cl1[:] = [6.0, -3.0, -3.0, 0.0]
            cx2[:] = [0.0, -0.5, 0.5, 0.0]
            cl2[:] = [0.0, -1.0, 1.0, 0.0]
        else:  # x1/l1 across, x2/l2 along
            d = k * (3.0 + c_)
            r = (1.0 + c_) / (k * s_ * (3.0 + c_))
            cx1[:, P] = np.sin(ip * tk)
            cx1[:, Q] = np.sin(iq * tk) + np.sin((iq + 1) * tk)
            cl1[:, 0] = -4.0 * s_ / d
            cl1[:, 1] = cl1[:, 1 + k] = -r * (1.0 + 2.0 * c_)
            cl1[:, 2:1 + k] = 4.0 * np.sin(np.arange(1, k) * tk) / d
            cl1[:, Q] = (np.sin(iq * tk) + np.sin((iq + 1) * tk)) / d
            cx2[:, P] = np.cos(ip * tk)
            cx2[:, Q] = np.cos(iq * tk) + np.cos((iq + 1) * tk)
            cl2[:, 1], cl2[:, 1 + k] = 0.5, -0.5
        cross = 1
    if k >= 2:
        # l_cross(s) = l_cross + s g3 m_hat (docs/rules.md section 6), for smooth creases with flatness
        lc = cl2 if cross == 2 else cl1
        g3 = lc[:, 0] - 4.0 * lc[:, 1]
        m_hat = np.zeros(n)
        m_hat[0], m_hat[1], m_hat[1 + k] = 1.0 / 3.0, -1.0 / 6.0, -1.0 / 6.0
        lc += (s * g3)[:, None] * m_hat
    return l0_crease, cl1, cl2, cx1, cx2


# --------------------------------------------------------------------------------------------------------
# local subdivision matrices and the masks that have no closed form (straight sectors, darts)


def sector_matrix(scheme: str, k: int, theta: float, centre: str = "corner") -> np.ndarray:
    """Local subdivision matrix of a sector of k faces over ``[c, p_0..p_k, (q_0..q_{k-1})]``.

    The rules of docs/rules.md sections 3 to 5: ``centre`` "corner" (c' = c) or "crease" (B-spline); crease
    edges are midpoints; the non-crease edges use the crease/corner-neighbour rule with gamma(theta); CC face
    points are centroids."""
    n = local_size(scheme, k, sector=True)
    S = np.zeros((n, n))
    if centre == "corner":
        S[0, 0] = 1.0
    else:
        S[0, 0], S[0, 1], S[0, 1 + k] = 0.75, 0.125, 0.125
    for end in (1, 1 + k):
        S[end, 0] = S[end, end] = 0.5
    g = float(gamma(scheme, theta))
    if scheme == LOOP:
        for i in range(1, k):
            r = 1 + i
            S[r, 0] += 0.75 - g
            S[r, r] += g
            S[r, r - 1] += 0.125
            S[r, r + 1] += 0.125
        return S
    faces = np.zeros((k, n))
    for i in range(k):
        faces[i, [0, 1 + i, 2 + i, k + 2 + i]] = 0.25
        S[k + 2 + i] = faces[i]
    for i in range(1, k):
        r = 1 + i
        S[r, 0] += 0.625 - g
        S[r, r] += g - 0.125
        S[r] += 0.25 * (faces[i - 1] + faces[i])
    return S


def dart_matrix(scheme: str, k: int, beta_variant: str = "loop") -> np.ndarray:
    """Local subdivision matrix of a dart of valence k over ``[c, p_0..p_{k-1}, (q_0..q_{k-1})]`` with p_0 on the
    crease edge: the interior vertex rule, the midpoint on the crease edge, smooth rules elsewhere (docs/rules.md
    sections 1, 3 to 5)."""
    n = local_size(scheme, k, sector=False)
    S = np.zeros((n, n))
    p = 1 + np.arange(k)
    if scheme == LOOP:
        centre, beta = (float(w) for w in _loop_interior(k, beta_variant))
        S[0, 0], S[0, p] = centre, beta
        for i in range(1, k):
            S[p[i], [0, p[i]]] = 0.375
            S[p[i], p[(i - 1) % k]] += 0.125
            S[p[i], p[(i + 1) % k]] += 0.125
    else:
        faces = np.zeros((k, n))
        for i in range(k):
            faces[i, [0, p[i], p[(i + 1) % k], 1 + k + i]] = 0.25
            S[1 + k + i] = faces[i]
        wc, wp, wf = (float(w) for w in catmull_clark_interior_vertex_weights(k))
        S[0, 0] = wc
        S[0, p] += wp
        S[0] += wf * faces.sum(axis=0)
        for i in range(1, k):
            S[p[i], [0, p[i]]] += 0.25
            S[p[i]] += 0.25 * (faces[i - 1] + faces[i])
    S[p[0], 0] = S[p[0], p[0]] = 0.5
    return S


def _loop_interior(k, beta_variant):
    beta = float(loop_beta(k, beta_variant))
    return 1.0 - k * beta, beta


def _null_space(a: np.ndarray, dim: int) -> np.ndarray:
    """(n, dim) orthonormal basis of the ``dim`` smallest singular directions of ``a``."""
    _, sv, vt = np.linalg.svd(a)
    sv = np.concatenate([sv, np.zeros(a.shape[1] - len(sv))])  # a wide matrix: the missing values are 0
    if sv[-dim] > 1e-8 * max(1.0, sv[0]) or (len(sv) > dim and sv[-dim - 1] < 1e-8):
        raise ArithmeticError(f"expected a null space of dimension {dim}, singular values {sv}")
    return vt[-dim:].T


def _frozen(d: dict) -> dict:
    for v in d.values():
        v.flags.writeable = False
    return d


@lru_cache(maxsize=None)
def straight_sector_vectors(scheme: str, k: int) -> dict:
    """Masks and right vectors of a straight sector of k >= 2 faces (docs/rules.md section 8.7), (n,) each.

    The sector's matrix is the corner matrix at k theta = pi (``sector_matrix(scheme, k, pi/k)``): eigenvalue
    1/2 is triple with a Jordan block of size 2. Its generalised left space is spanned by the along mask
    (e_p0 - e_pk)/2, the kink mask (e_p0 + e_pk)/2 - e_c and one vector with no weight on p_0 and p_k, the
    across mask, scaled so that its right vector is sin(i pi/k) on p_i like a crease's. The right vectors are
    the dual basis inside the generalised right space, so x^0 l^0 + sum x^m l^m is its spectral projector."""
    if k < 2:
        raise ValueError("a straight sector has at least two faces")
    S = sector_matrix(scheme, k, np.pi / k)
    n = len(S)
    a = S - 0.5 * np.eye(n)
    right = _null_space(a @ a, 3)
    left = _null_space((a @ a).T, 3)
    ends = [1, 1 + k]
    across = left @ _null_space(left[ends], 1)[:, 0]
    across[ends] = 0.0  # exactly (the null space leaves rounding there)
    along = np.zeros(n)
    along[1], along[1 + k] = 0.5, -0.5
    kink = np.zeros(n)
    kink[0], kink[1], kink[1 + k] = -1.0, 0.5, 0.5
    lefts = np.stack([along, across, kink])
    xs = right @ np.linalg.inv(lefts @ right)  # (n, 3) with lefts @ xs = I
    scale = np.sin(np.pi / k) / xs[2, 1]  # x^2 at p_1 = sin(pi/k)
    lefts[1] /= scale
    xs[:, 1] *= scale
    l0 = np.zeros(n)
    l0[0] = 1.0
    return _frozen(dict(l0=l0, l1=lefts[0], l2=lefts[1], l3=lefts[2], x1=xs[:, 0], x2=xs[:, 1], x3=xs[:, 2]))


def _reflection(scheme: str, k: int) -> np.ndarray:
    """Permutation of a ring's local vector mirroring it across the line through c and p_0."""
    idx = [0] + [1 + (-i) % k for i in range(k)]
    if scheme == CATMULL_CLARK:
        idx += [1 + k + (-i - 1) % k for i in range(k)]
    return np.array(idx)


@lru_cache(maxsize=None)
def dart_vectors(scheme: str, k: int, beta_variant: str = "loop") -> dict:
    """Masks and right vectors of a dart of valence k (docs/rules.md section 8.8), (n,) each, p_0 on the crease.

    Computed from ``dart_matrix``: the matrix commutes with the mirror across the crease edge, so its left
    eigenvectors are symmetric or antisymmetric. l0 is the left eigenvector of 1 (summing to 1); l1 the leading
    symmetric one (the tangent along the crease), l2 the leading antisymmetric one (across it); each right
    vector is scaled to l^m . x^m = 1, and signs are fixed so that for a ring laid out counter-clockwise in the
    plane, l1 . p points toward p_0 and l2 . p to the side of p_1: tu x tv = l1 x l2 is the outward normal."""
    S = dart_matrix(scheme, k, beta_variant)
    n = len(S)
    perm = _reflection(scheme, k)
    mirror = np.eye(n)[perm]
    vals, vecs = np.linalg.eigh(0.5 * (mirror + mirror.T))
    out = {}
    found = []
    for sign, name in ((1.0, "sym"), (-1.0, "anti")):
        basis = vecs[:, np.isclose(vals, sign)]
        block = basis.T @ S @ basis
        lam, y = np.linalg.eig(block.T)
        lam_r, z_r = np.linalg.eig(block)
        order = np.argsort(-np.abs(lam))
        if name == "sym":
            if not np.isclose(lam[order[0]], 1.0):
                raise ArithmeticError("dart matrix: eigenvalue 1 must lead")
            l0 = np.real(basis @ y[:, order[0]])
            out["l0"] = l0 / l0.sum()
            order = order[1:]
        mu = lam[order[0]]
        if abs(mu.imag) > 1e-12:
            raise ArithmeticError(f"dart matrix: complex subdominant eigenvalue {mu}")
        left = np.real(basis @ y[:, order[0]])
        right = np.real(basis @ z_r[:, np.argmin(np.abs(lam_r - mu))])
        right /= left @ right
        found.append((float(mu.real), left, right, np.abs(lam[order[1:]])))
    # tangent plane: the two leading modes must dominate everything else
    rest = np.concatenate([f[3] for f in found])
    if len(rest) and rest.max() >= min(found[0][0], found[1][0]) - 1e-12:
        raise ArithmeticError(f"dart of valence {k}: the symmetric and antisymmetric modes do not lead")
    ang = 2.0 * np.pi * np.arange(k) / k
    ring = [np.zeros(2)] + [np.array([np.cos(a), np.sin(a)]) for a in ang]
    if scheme == CATMULL_CLARK:
        ring += [1.5 * np.array([np.cos(a + np.pi / k), np.sin(a + np.pi / k)]) for a in ang]
    ring = np.array(ring)
    for m, (mu, left, right, _) in enumerate(found, start=1):
        axis = m - 1  # sym: along x (toward p_0); anti: along y (toward p_1)
        if left @ ring[:, axis] < 0:
            left, right = -left, -right
        out[f"l{m}"], out[f"x{m}"] = left, right
        out[f"lambda{m}"] = np.array(mu)
    return _frozen(out)


def dart_masks(scheme: str, k: int, count: int, beta_variant: str = "loop") -> LocalMasks:
    """A dart of valence k (docs/rules.md section 8.8), over ``[c, p_0..p_{k-1}, (q_0..q_{k-1})]`` with p_0 the
    far end of the crease edge; (count, n) read-only broadcasts of one row, as :func:`interior_masks`."""
    v = dart_vectors(scheme, k, beta_variant)
    n = local_size(scheme, k, sector=False)
    rows = {m: np.broadcast_to(v[m], (count, n)) for m in ("l0", "l1", "l2", "x1", "x2")}
    return LocalMasks(rows["l0"], rows["l1"], rows["l2"], rows["x1"], rows["x2"], tu=rows["l1"], tv=rows["l2"])


def use_opensubdiv_tangents(m: LocalMasks, scheme: str, kind: np.ndarray, k: int) -> None:
    """Replace the tangent masks (tu, tv) by OpenSubdiv's where their directions differ from the paper's.

    Corners: tu = p_0 - c and tv = p_1 - c (OpenSubdiv's second corner tangent follows the vertex's second
    edge, the first interior one when k >= 2). Loop crease sectors of k >= 4 faces: OpenSubdiv's cross
    tangent, -sin(theta) on p_0 and p_k and -2 (cos(theta) - 1) sin(i theta) on p_i, theta = pi/k, oriented
    into the surface, with the along tangent p_0 - p_k."""
    corner = np.asarray(kind) != SECTOR_CREASE
    n = m.tu.shape[1]
    if np.any(corner):
        tu = np.zeros(n)
        tu[0], tu[1] = -1.0, 1.0
        tv = np.zeros(n)
        tv[0], tv[2] = -1.0, 1.0  # p_1 (= p_k when k = 1)
        m.tu[corner] = tu
        m.tv[corner] = tv
    crease = ~corner
    if scheme == LOOP and k >= 4 and np.any(crease):
        theta = np.pi / k
        along = np.zeros(n)
        along[1], along[1 + k] = 1.0, -1.0
        cross = np.zeros(n)
        cross[1] = cross[1 + k] = -np.sin(theta)
        cross[2:1 + k] = -2.0 * (np.cos(theta) - 1.0) * np.sin(np.arange(1, k) * theta)
        m.tu[crease] = along
        m.tv[crease] = cross


def flattened_points(scheme: str, k: int) -> np.ndarray:
    """Local indices of the non-crease ring points that flatness moves: Loop p_1..p_{k-1}; CC also all q_i."""
    inner = np.arange(2, k + 1)
    if scheme == CATMULL_CLARK:
        return np.concatenate([inner, np.arange(k + 2, 2 * k + 2)])
    return inner


def _mu_plus(theta, phi):
    b = 2.5 - np.cos(theta) + 0.5 * np.cos(phi)
    return (b + np.sqrt(np.maximum(b * b - 4.0 * (1.0 - np.cos(theta)), 0.0))) / 8.0


def optimal_flatness(scheme: str, kind, k, theta):
    """s* = max(0, 1 - 1/(4 mu_max)): the largest scaled eigenvalue becomes lambda^2 = 1/4.

    docs/rules.md sections 6 and 11."""
    kind = np.asarray(kind)
    k = np.asarray(k, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    tk = np.pi / k
    if scheme == LOOP:
        mu_crease = np.where(k >= 3, gamma(LOOP, tk) + 0.25 * np.cos(2 * tk), 0.25)
        mu_corner = np.where(k >= 2, (2.0 + np.cos(tk) - np.cos(theta)) / 4.0, 0.25)
    else:
        mu_crease = np.where(k >= 3, np.maximum(0.25, _mu_plus(tk, 2 * tk)), 0.25)
        mu_corner = np.where(k >= 2, np.maximum(0.25, _mu_plus(theta, tk)), 0.25)
    # a straight sector's scaled spectrum is a crease's of the same k without the crease's 1/4 (section 8.7)
    mu = np.where((kind == SECTOR_CREASE) | (kind == SECTOR_STRAIGHT), mu_crease, mu_corner)
    s = 1.0 - 1.0 / (4.0 * mu)
    return np.where(s > 1e-12, s, 0.0)  # exactly 0 where mu_max = 1/4 (regular creases), despite rounding


def concave_min_flatness(scheme: str, k, theta):
    """s_min of a concave sector: the smallest s that makes 1/2 subdominant (docs/rules.md section 6, "Valid s")."""
    k = np.asarray(k, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    tk = np.pi / k
    if scheme == LOOP:
        return 1.0 - 2.0 / (2.0 + np.cos(tk) - np.cos(theta))
    return 1.0 - 1.0 / (2.0 * _mu_plus(theta, tk))
