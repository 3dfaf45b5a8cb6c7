"""Ray-casting kernels for previews: one ray per sample against a ``wp.Mesh`` (a triangle soup, three corners per
triangle), simple shading (headlight, key light with a shadow ray, ambient, a little specular)."""
import warp as wp

# Forward evaluation only: no adjoint code (faster compiles, smaller modules).
wp.set_module_options({"enable_backward": False})


@wp.func
def camera_ray(x: float, y: float, eye: wp.vec3, forward: wp.vec3, right: wp.vec3, up: wp.vec3, ortho: int):
    """(origin, direction) of the ray through screen point (x, y) in [-1, 1]^2; right/up are pre-scaled."""
    if ortho != 0:
        return eye + x * right + y * up, wp.normalize(forward)
    return eye, wp.normalize(forward + x * right + y * up)


@wp.kernel
def shade_samples(
    mesh: wp.uint64,
    corner_normals: wp.array(dtype=wp.vec3),
    corner_colors: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    forward: wp.vec3,
    right: wp.vec3,
    up: wp.vec3,
    ortho: int,
    width: int,
    height: int,
    key_light: wp.vec3,
    sky: wp.vec3,
    max_t: float,
    color: wp.array2d(dtype=wp.vec3),
    cover: wp.array2d(dtype=float),
    depth: wp.array2d(dtype=float),
):
    """One thread per sample (row, column) of a width x height sample grid: colour, coverage and distance."""
    j, i = wp.tid()
    x = (float(i) + 0.5) / float(width) * 2.0 - 1.0
    y = 1.0 - (float(j) + 0.5) / float(height) * 2.0
    origin, d = camera_ray(x, y, eye, forward, right, up, ortho)
    hit = wp.mesh_query_ray(mesh, origin, d, max_t)
    if not hit.result:
        cover[j, i] = 0.0
        color[j, i] = wp.vec3(0.0, 0.0, 0.0)
        depth[j, i] = max_t
        return
    f = hit.face
    w = 1.0 - hit.u - hit.v
    n = hit.u * corner_normals[3 * f] + hit.v * corner_normals[3 * f + 1] + w * corner_normals[3 * f + 2]
    if wp.length(n) < 1.0e-12:
        n = hit.normal
    n = wp.normalize(n)
    if wp.dot(n, d) > 0.0:
        n = -n  # two-sided
    base = hit.u * corner_colors[3 * f] + hit.v * corner_colors[3 * f + 1] + w * corner_colors[3 * f + 2]
    p = origin + hit.t * d
    diffuse = wp.max(wp.dot(n, key_light), 0.0)
    if diffuse > 0.0:
        shadow = wp.mesh_query_ray(mesh, p + n * (1.0e-4 * max_t), key_light, max_t)
        if shadow.result:
            diffuse = diffuse * 0.3
    head = wp.max(-wp.dot(n, d), 0.0)
    hemi = 0.5 + 0.5 * wp.dot(n, sky)
    h = wp.normalize(key_light - d)
    spec = wp.pow(wp.max(wp.dot(n, h), 0.0), 40.0) * 0.18
    light = 0.08 + 0.1 * hemi + 0.7 * diffuse + 0.22 * head
    color[j, i] = base * light + wp.vec3(spec, spec, spec)
    cover[j, i] = 1.0
    depth[j, i] = hit.t
