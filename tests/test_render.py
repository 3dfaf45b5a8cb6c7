"""Previews: Warp ray casting to a PNG of the requested size that shows the meshes, the PNG writer, framing."""
import os
import struct
import zlib

import numpy as np
import pytest

from test_usd_support import SCENES_DIR
from warp_subdiv.render import (BACKGROUND_BOTTOM, BACKGROUND_TOP, framing_camera, png_bytes, read_png_size,
                                render_file)


def decode_png(data: bytes) -> np.ndarray:
    """A minimal decoder for the 8-bit RGB PNGs the renderer writes (written independently of the encoder)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, width = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        assert zlib.crc32(kind + body) & 0xFFFFFFFF == struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])[0]
        if kind == b"IHDR":
            width, height, depth, color = struct.unpack(">IIBB", body[:10])
            assert (depth, color) == (8, 2)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw = zlib.decompress(idat)
    stride = 3 * width
    out = np.zeros((height, stride), dtype=np.int64)
    prev = np.zeros(stride, dtype=np.int64)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        line = np.frombuffer(raw, np.uint8, stride, y * (stride + 1) + 1).astype(np.int64)
        cur = np.zeros(stride, dtype=np.int64)
        for x in range(stride):
            a = cur[x - 3] if x >= 3 else 0
            b = prev[x]
            c = prev[x - 3] if x >= 3 else 0
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (line[x] + pred) % 256
        out[y] = cur
        prev = cur
    return out.reshape(height, width, 3).astype(np.uint8)


def is_background(img: np.ndarray) -> np.ndarray:
    rows = np.linspace(0.0, 1.0, img.shape[0])[:, None, None]
    bg = np.round(255 * (BACKGROUND_TOP * (1 - rows) + BACKGROUND_BOTTOM * rows))
    return np.all(np.abs(img.astype(np.float64) - bg) <= 2, axis=2)


def test_png_writer_round_trips():
    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, size=(7, 11, 3), dtype=np.uint8)
    img[3:] = img[2]  # rows that repeat: the Up filter wins there
    np.testing.assert_array_equal(decode_png(png_bytes(img)), img)


def test_render_writes_a_png_of_the_requested_size_showing_the_meshes(tmp_path):
    out = tmp_path / "sub" / "preview.png"
    img = render_file(os.path.join(SCENES_DIR, "twisted_boundary.usda"), str(out), size=(72, 40), samples=1,
                      levels=1, device="cpu", view=(-100.0, 30.0))
    assert read_png_size(str(out)) == (72, 40)
    pixels = decode_png(out.read_bytes())
    np.testing.assert_array_equal(pixels, img)
    shown = ~is_background(pixels)
    assert 0.1 < shown.mean() < 0.95  # the meshes fill a good part of the frame, not all of it
    assert len(np.unique(pixels[shown].reshape(-1, 3), axis=0)) > 20  # shaded, not flat
    # two coloured variants side by side: warm on the left, cool on the right
    left, right = pixels[:, :36][shown[:, :36]], pixels[:, 36:][shown[:, 36:]]
    assert left[:, 0].mean() > left[:, 2].mean() and right[:, 2].mean() > right[:, 0].mean()
    assert [f for f in os.listdir(out.parent)] == ["preview.png"]


def test_render_command_with_cage_and_prim(tmp_path, capsys):
    from warp_subdiv import cli

    src = os.path.join(SCENES_DIR, "concave_corner.usda")
    plain, caged = tmp_path / "plain.png", tmp_path / "caged.png"
    args = ["render", src, "--prim", "/World/PiecewiseSmooth/LPlate", "--size", "48x32", "--samples", "1",
            "--levels", "1", "--device", "cpu", "--view", "-90", "60"]
    assert cli.main(args + ["-o", str(plain)]) == 0, capsys.readouterr().err
    assert cli.main(args + ["-o", str(caged), "--cage", src]) == 0, capsys.readouterr().err
    a, b = decode_png(plain.read_bytes()), decode_png(caged.read_bytes())
    assert a.shape == b.shape == (32, 48, 3)
    changed = np.any(a != b, axis=2)
    assert changed.mean() > 0.02 and (b[changed].astype(int).sum(axis=1) < a[changed].astype(int).sum(axis=1)).mean() > 0.8
    assert cli.main(["render", src, "-o", str(tmp_path / "x.jpg")]) == 2
    assert "written as .png" in capsys.readouterr().err


def test_framing_camera_sees_every_point():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200, 3)) * [3.0, 1.0, 0.2] + [10.0, -4.0, 2.0]
    for view in ((-60.0, 30.0), (45.0, 80.0), (180.0, -20.0)):
        cam = framing_camera(pts, view, 16 / 9, "Z")
        x, y, dist = cam.project(pts, 160, 90)
        assert np.all((x > 0) & (x < 160) & (y > 0) & (y < 90) & (dist > 0)), view
        assert max(x.max() - x.min(), (y.max() - y.min()) * 16 / 9) > 0.7 * 160  # and fills the frame


@pytest.mark.parametrize("text", ["12", "axb", "0x10"])
def test_bad_resolutions_are_usage_errors(text):
    from warp_subdiv.errors import SubdivInputError
    from warp_subdiv.render import parse_resolution

    with pytest.raises(SubdivInputError, match=f"^size {text!r}: ") as info:
        parse_resolution(text)
    assert info.value.option == "size"


def test_render_through_a_usd_camera(tmp_path):
    from pxr import Gf, Usd, UsdGeom

    path = tmp_path / "cam.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.GetRootLayer().subLayerPaths.append(os.path.join(SCENES_DIR, "twisted_boundary.usda"))
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    UsdGeom.XformCommonAPI(cam).SetTranslate(Gf.Vec3d(1.5, -6.0, 3.0))
    UsdGeom.XformCommonAPI(cam).SetRotate(Gf.Vec3f(65.0, 0.0, 0.0))
    stage.GetRootLayer().Save()
    out = tmp_path / "cam.png"
    img = render_file(str(path), str(out), camera="/Cam", size=(64, 36), samples=1, device="cpu")
    shown = ~is_background(img)
    assert 0.05 < shown.mean() < 0.9
    # looking up from below instead: the camera turned away sees nothing
    UsdGeom.XformCommonAPI(cam).SetRotate(Gf.Vec3f(-90.0, 0.0, 0.0))
    stage.GetRootLayer().Save()
    img = render_file(str(path), str(tmp_path / "away.png"), camera="/Cam", size=(64, 36), samples=1, device="cpu")
    assert is_background(img).all()


def _cube(size):
    pts = np.array([(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=np.float64) * size / 2
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return pts, [4] * 6, [i for f in faces for i in f]


RED, GREEN, BLUE, YELLOW = (0.9, 0.1, 0.1), (0.1, 0.8, 0.1), (0.1, 0.1, 0.9), (0.9, 0.9, 0.1)


def purpose_stage(path):
    """An asset as pipelines publish it: a subdivision cube of render purpose and, under the same Xform, a
    larger proxy cage around it (purpose authored on its parent Xform, so the cage inherits it; the render
    mesh's proxyPrim names the cage); a ground plane of default purpose and a guide mesh beside them."""
    from pxr import Gf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Xform.Define(stage, "/World/Asset")

    def mesh(where, pts, counts, idx, color, scheme="catmullClark"):
        m = UsdGeom.Mesh.Define(stage, where)
        m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
        m.CreateFaceVertexCountsAttr(Vt.IntArray(counts))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
        m.CreateSubdivisionSchemeAttr(scheme)
        m.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*color)]))
        return m

    render = mesh("/World/Asset/Render", *_cube(1.0), RED)
    render.CreatePurposeAttr(UsdGeom.Tokens.render)
    UsdGeom.Xform.Define(stage, "/World/Asset/Proxy").CreatePurposeAttr(UsdGeom.Tokens.proxy)
    mesh("/World/Asset/Proxy/Cage", *_cube(1.6), BLUE)
    render.CreateProxyPrimRel().SetTargets(["/World/Asset/Proxy/Cage"])
    ground = [(-3, -3, -1), (3, -3, -1), (3, 3, -1), (-3, 3, -1)]
    mesh("/World/Ground", ground, [4], [0, 1, 2, 3], GREEN, scheme="none")
    guide = mesh("/World/Guide", [(p[0] + 8, p[1], p[2]) for p in _cube(1.0)[0]], *_cube(1.0)[1:], YELLOW)
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    stage.GetRootLayer().Save()
    return stage


def test_meshes_are_drawn_by_their_purpose_as_a_renderer_draws_them(tmp_path):
    """A renderer draws default-purpose geometry and one of render or proxy (render by default), never guides:
    drawing the proxy cage with the render mesh hid the refined mesh inside it."""
    from warp_subdiv.errors import SubdivInputError
    from warp_subdiv.render import cage_edges, stage_soup

    stage = purpose_stage(tmp_path / "asset.usda")
    colors = {purpose: {tuple(np.round(c, 1)) for c in stage_soup(stage, purpose=purpose).colors}
              for purpose in ("render", "proxy")}
    assert colors["render"] == {RED, GREEN}
    assert colors["proxy"] == {BLUE, GREEN}
    assert np.abs(cage_edges(stage)).max() == pytest.approx(0.5)  # the render mesh's control cage only
    assert np.abs(cage_edges(stage, purpose="proxy")).max() == pytest.approx(0.8)
    with pytest.raises(SubdivInputError, match="^purpose 'guide': ") as info:
        stage_soup(stage, purpose="guide")
    assert info.value.option == "purpose"


def test_render_command_draws_the_render_purpose_or_the_one_asked(tmp_path, capsys):
    from warp_subdiv import cli

    src = tmp_path / "asset.usda"
    purpose_stage(src)
    args = ["render", str(src), "--size", "40x30", "--samples", "1", "--device", "cpu", "--prim", "/World/Asset"]

    def hues(img):
        img = img.astype(int)
        return (img[..., 0] > img[..., 2] + 60).sum(), (img[..., 2] > img[..., 0] + 60).sum()

    assert cli.main(args + ["-o", str(tmp_path / "render.png"), "--levels", "1"]) == 0, capsys.readouterr().err
    red, blue = hues(decode_png((tmp_path / "render.png").read_bytes()))
    assert red > 100 and blue == 0
    assert cli.main(args + ["-o", str(tmp_path / "proxy.png"), "--purpose", "proxy"]) == 0, capsys.readouterr().err
    red, blue = hues(decode_png((tmp_path / "proxy.png").read_bytes()))
    assert blue > 100 and red == 0
    # a prim of the other purpose only: nothing drawn, and the message says why and what draws it
    assert cli.main(["render", str(src), "-o", str(tmp_path / "none.png"), "--prim", "/World/Asset/Proxy"]) == 2
    err = capsys.readouterr().err
    assert "1 proxy-purpose mesh is left out (the --purpose option chooses proxy)" in err, err
    assert cli.main(["render", str(src), "-o", str(tmp_path / "none.png"), "--prim", "/World/Guide"]) == 2
    assert "1 guide-purpose mesh is left out (no renderer draws guides)" in capsys.readouterr().err
    assert cli.main(["render", str(src), "-o", str(tmp_path / "guide.png"), "--purpose", "guide"]) == 2
    assert "invalid choice: 'guide'" in capsys.readouterr().err
    cube = os.path.join(SCENES_DIR, "cube_creased.obj")
    assert cli.main(["render", cube, "-o", str(tmp_path / "obj.png"), "--purpose", "proxy"]) == 2
    assert "--purpose applies to USD input only" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["asset.usda", "proxy.png", "render.png"]
