"""Fit the control points of a creased Catmull-Clark cage to a point set (gradients of warp_subdiv).

The cage is a box of 2 x 2 quads per side, its top rim an infinitely sharp crease and its bottom rim a
semi-sharp one (sharpness 2). The target is a point set without correspondences: the points of the level-3 surface of
a hidden cage (the same box twisted, tapered and bulged), shuffled, with a little noise. Starting from the
plain box, Adam moves the 26 control points to minimise the symmetric chamfer distance between the level-3
surface and the target: the loss and its gradient with respect to the refined points are computed in numpy
(nearest neighbours), and ``Refiner.evaluate_vjp`` (the transposed subdivision tables) carries the gradient
back to the cage. Prints the loss curve and renders a before / after preview (surface coloured by the distance
to the nearest target point, cage drawn over it).

    .venv/bin/python scenes/fit_cage.py                     # writes docs/fit_cage.png
    .venv/bin/python scenes/fit_cage.py --steps 300 -o out/fit.png

Runs on the CPU in a few seconds.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def box_cage(n: int = 2):
    """A box [-1, 1]^3 of n x n quads per side: (points, counts, indices), outward faces."""
    grid = np.linspace(-1.0, 1.0, n + 1)
    points, index = [], {}

    def vid(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(points)
            points.append(p)
        return index[key]

    faces = []
    for axis in range(3):
        for side in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            for i in range(n):
                for j in range(n):
                    quad = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis], p[u], p[v] = side, grid[i + di], grid[j + dj]
                        quad.append(vid(p))
                    # outward: (u, v, axis) right-handed for side +1
                    if (side > 0) != ((u, v, axis) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))):
                        quad = quad[::-1]
                    faces.append(quad)
    points = np.array(points)
    return points, np.full(len(faces), 4, np.int32), np.array(faces, np.int32).reshape(-1)


def rim_edges(points, counts, indices, y: float):
    """The cage edges that run around the box at height ``y`` (both ends there, on the box's side)."""
    nxt = np.arange(len(indices)) + 1
    nxt[3::4] -= 4
    pairs = np.unique(np.sort(np.stack([indices, indices[nxt]], axis=1), axis=1), axis=0)
    a, b = points[pairs[:, 0]], points[pairs[:, 1]]
    on_rim = (np.abs(a[:, 1] - y) < 1e-9) & (np.abs(b[:, 1] - y) < 1e-9)
    outer = (np.max(np.abs(a[:, [0, 2]]), axis=1) > 1 - 1e-9) & (np.max(np.abs(b[:, [0, 2]]), axis=1) > 1 - 1e-9)
    return pairs[on_rim & outer]


def deform(points):
    """The hidden shape: twisted by up to 25 degrees about y, tapered toward the top, bulged at mid height."""
    x, y, z = points.T
    t = 0.5 * (y + 1.0)
    angle = np.radians(25.0) * t
    scale = (1.0 - 0.35 * t) * (1.0 + 0.25 * np.sin(np.pi * t))
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([scale * (c * x - s * z), 1.2 * y, scale * (s * x + c * z)], axis=1)


def chamfer(x, target):
    """Symmetric chamfer distance (mean squared nearest distances both ways) and its gradient in x."""
    d = np.sum(x * x, 1)[:, None] - 2.0 * x @ target.T + np.sum(target * target, 1)[None, :]
    a = np.argmin(d, axis=1)  # nearest target point of each surface point
    b = np.argmin(d, axis=0)  # nearest surface point of each target point
    fwd, bwd = x - target[a], x[b] - target
    loss = np.mean(np.sum(fwd * fwd, 1)) + np.mean(np.sum(bwd * bwd, 1))
    grad = 2.0 * fwd / len(x)
    np.add.at(grad, b, 2.0 * bwd / len(target))
    return loss, grad


def laplacian(counts, indices, n):
    """The cage's uniform Laplacian (n, n) as a dense matrix: each point minus the mean of its edge neighbours."""
    nxt = np.arange(len(indices)) + 1
    nxt[np.cumsum(counts) - 1] -= counts
    adj = np.zeros((n, n))
    adj[indices, indices[nxt]] = adj[indices[nxt], indices] = 1.0
    return np.eye(n) - adj / adj.sum(1, keepdims=True)


def sparkline(values) -> str:
    bars = " .:-=+*#%@"
    v = np.log10(np.asarray(values))
    v = (v - v.min()) / max(v.max() - v.min(), 1e-12)
    return "".join(bars[int(round(t * (len(bars) - 1)))] for t in v)


def render_panel(refiner, cage_points, target, camera, size, device):
    from warp_subdiv import render

    counts, indices = refiner.topology()
    x = refiner.evaluate(cage_points)
    d = np.sqrt(np.min(np.sum((x[:, None, :] - target[None, :, :]) ** 2, axis=2), axis=1))
    t = np.clip(d / 0.12, 0.0, 1.0)[:, None]
    colours = (1 - t) * np.array([0.25, 0.55, 0.95]) + t * np.array([0.95, 0.35, 0.2])  # blue near, red far
    normals = render.corner_normals(x, counts, indices)
    soup = render._soup(x, counts, indices, normals, colours[indices])
    c, i = refiner.mesh.face_vertex_counts, refiner.mesh.face_vertex_indices.astype(np.int64)
    nxt = np.arange(len(i)) + 1
    nxt[np.cumsum(c) - 1] -= c
    edges = cage_points[np.unique(np.sort(np.stack([i, i[nxt]], axis=1), axis=1), axis=0)]
    return render.render_soup(soup, camera, size[0], size[1], samples=2, device=device, edges=edges)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("-o", "--output", default=os.path.join(ROOT, "docs", "fit_cage.png"), help="preview PNG")
    p.add_argument("--steps", type=int, default=200, help="Adam steps (default 200)")
    p.add_argument("--lr", type=float, default=0.05, help="Adam learning rate (default 0.05)")
    p.add_argument("--smooth", type=float, default=1e-3, help="weight of the Laplacian term (default 1e-3)")
    p.add_argument("--no-render", action="store_true", help="skip the preview")
    args = p.parse_args(argv)

    sys.path.insert(0, ROOT)
    import warp as wp

    wp.config.quiet = True
    import warp_subdiv as ws
    from warp_subdiv import render

    points, counts, indices = box_cage(2)
    top, bottom = rim_edges(points, counts, indices, 1.0), rim_edges(points, counts, indices, -1.0)
    creases = np.concatenate([top, bottom])
    sharpness = np.r_[np.full(len(top), 10.0), np.full(len(bottom), 2.0)]
    mesh = ws.Mesh(points, counts, indices, creases=creases, crease_sharpness=sharpness)
    refiner = ws.Refiner(mesh, 3, precision="float64", device="cpu")

    rng = np.random.default_rng(0)
    surface = refiner.evaluate(deform(points))  # the hidden cage's level 3, shuffled: no correspondences
    target = surface[rng.permutation(len(surface))] + 0.003 * rng.standard_normal(surface.shape)

    t0 = time.perf_counter()
    # start from the box fitted to the target's bounding box; a small Laplacian term keeps the cage from folding
    lo, hi = target.min(0), target.max(0)
    cage = 0.5 * (lo + hi) + 0.5 * (hi - lo) * points
    lap = laplacian(counts, indices.astype(np.int64), len(points))
    rest = lap @ cage
    m, v = np.zeros_like(cage), np.zeros_like(cage)
    beta1, beta2 = 0.9, 0.999
    losses = []
    print(f"cage: {len(points)} control points, {len(counts)} quads, {len(top)} sharp and {len(bottom)} semi-sharp "
          f"crease edges; level 3: {refiner.num_vertices} points; target: {len(target)} points")
    for step in range(1, args.steps + 1):
        x = refiner.evaluate(cage)
        loss, grad_x = chamfer(x, target)
        grad = refiner.evaluate_vjp(grad_x)  # d loss / d control points: the transposed tables
        grad += 2.0 * args.smooth * lap.T @ (lap @ cage - rest)
        losses.append(loss)
        if step == 1 or step % 20 == 0 or step == args.steps:
            print(f"step {step:4d}  chamfer {loss:.6f}")
        m = beta1 * m + (1 - beta1) * grad
        v = beta2 * v + (1 - beta2) * grad * grad
        lr = args.lr * (0.1 ** (step / args.steps))  # decay to a tenth
        cage -= lr * (m / (1 - beta1 ** step)) / (np.sqrt(v / (1 - beta2 ** step)) + 1e-12)
    final, _ = chamfer(refiner.evaluate(cage), target)
    print(f"loss curve (log scale, {len(losses)} steps): {sparkline(losses[::max(1, len(losses) // 60)])}")
    print(f"chamfer {losses[0]:.6f} -> {final:.6f} ({losses[0] / final:.0f}x lower) in "
          f"{time.perf_counter() - t0:.1f} s; cage error to the hidden cage: "
          f"{np.sqrt(np.mean(np.sum((cage - deform(points)) ** 2, 1))):.4f} (rms)")

    if not args.no_render:
        size = (480, 420)
        camera = render.framing_camera(np.concatenate([target, points]), (-35.0, 25.0), size[0] / size[1])
        before = render_panel(refiner, points, target, camera, size, "cpu")
        after = render_panel(refiner, cage, target, camera, size, "cpu")
        gap = np.full((size[1], 8, 3), 255, np.uint8)
        render.write_png(args.output, np.concatenate([before, gap, after], axis=1))
        print(f"wrote {args.output} (left: the initial box, right: the fitted cage; blue: on the target, red: "
              f"0.12 or more away)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
