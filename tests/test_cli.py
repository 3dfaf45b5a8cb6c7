"""The command line as a user runs it, and the README / CI contract."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh, mesh_path
from warp_subdiv.objio import read_obj

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(*args, cwd=None):
    env = dict(os.environ)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "warp_subdiv", *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=120)


def test_refine_writes_the_refined_mesh(tmp_path):
    out = tmp_path / "sub" / "cube.obj"
    res = run("refine", mesh_path("cube_creased"), "-o", str(out), "--levels", "2", "--device", "cpu",
              "--precision", "float64")
    assert res.returncode == 0, res.stderr
    assert "faces 6 -> 96" in res.stdout
    back = read_obj(str(out)).mesh
    expected = ws.refine(load_mesh("cube_creased"), 2, device="cpu", precision="float64")
    np.testing.assert_allclose(back.points, expected.points, atol=1e-8)
    np.testing.assert_array_equal(back.face_vertex_indices, expected.face_vertex_indices)


def test_auto_scheme_picks_loop_for_triangles(tmp_path):
    out = tmp_path / "ico.obj"
    res = run("refine", mesh_path("icosahedron"), "-o", str(out), "--levels", "1", "--device", "cpu")
    assert res.returncode == 0 and "loop" in res.stdout
    assert read_obj(str(out)).mesh.num_faces == 80


@pytest.mark.parametrize("args,needle", [
    (["refine", "missing.obj", "-o", "x.obj", "--levels", "1"], "no such file"),
    (["refine", "README.md", "-o", "x.obj", "--levels", "1"], "only .obj"),
    (["refine", "{bad}", "-o", "x.obj", "--levels", "1"], "face 0"),
    (["refine", "{cube}", "-o", "x.obj", "--levels", "-1"], "levels"),
])
def test_user_errors_exit_2_with_one_line(tmp_path, args, needle):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    args = [a.format(bad=bad, cube=mesh_path("cube")) for a in args]
    res = run(*args, cwd=tmp_path)
    assert res.returncode == 2
    lines = [l for l in res.stderr.splitlines() if l.startswith("warp-subdiv")]
    assert len(lines) == 1 and needle in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "x.obj").exists()


def test_unwritable_output_leaves_no_file(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        res = run("refine", mesh_path("cube"), "-o", str(locked / "out.obj"), "--levels", "1", "--device", "cpu")
        assert res.returncode == 2 and "Traceback" not in res.stderr
        assert os.listdir(locked) == []
    finally:
        locked.chmod(0o700)


def test_failed_write_leaves_no_partial_file(tmp_path, monkeypatch):
    from warp_subdiv import objio

    def boom(*a, **k):
        raise OSError("disk full")

    target = tmp_path / "out.obj"
    monkeypatch.setattr(objio.np, "savetxt", boom)
    with pytest.raises(OSError):
        objio.write_obj(str(target), np.zeros((3, 3)), [3], [0, 1, 2])
    assert os.listdir(tmp_path) == []


def quick_start_commands():
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return [line for block in re.findall(r"```bash\n(.*?)```", section, re.S)
            for line in block.splitlines() if line and not line.startswith("#")]


def test_ci_runs_the_readme_test_command():
    commands = quick_start_commands()
    assert len(commands) == 2
    ci = open(os.path.join(ROOT, ".ci", "run"), encoding="utf-8").read()
    assert commands[1] in ci.splitlines()
    # the first command refines a bundled scene that exists
    scene = re.search(r"(scenes/\S+)", commands[0]).group(1)
    assert os.path.isfile(os.path.join(ROOT, scene))
