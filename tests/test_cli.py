"""The command line as a user runs it, and the README / CI contract."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest

import warp_subdiv as ws
from conftest import load_mesh, mesh_path
from warp_subdiv.io.obj import read_obj

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
    from warp_subdiv.io import obj as objio

    def boom(*a, **k):
        raise OSError("disk full")

    target = tmp_path / "out.obj"
    monkeypatch.setattr(objio, "_write_faces", boom)  # after the vertices: a file half written
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


def test_internal_errors_exit_1_with_the_debug_hint(tmp_path, monkeypatch, capsys):
    """Only input errors exit 2: a plain ValueError from inside (a bug) exits 1 with one line that says it is
    an internal error and how to see the traceback; WARP_SUBDIV_DEBUG=1 lets the exception through."""
    from warp_subdiv import cli
    from warp_subdiv.io import obj as objio

    def broken(path):
        raise ValueError("something inside went wrong")

    monkeypatch.setattr(objio, "read_obj", broken)
    monkeypatch.delenv("WARP_SUBDIV_DEBUG", raising=False)
    args = ["refine", mesh_path("cube"), "-o", str(tmp_path / "x.obj"), "--levels", "1", "--device", "cpu"]
    assert cli.main(args) == 1
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warp-subdiv")]
    assert len(lines) == 1 and lines[0].startswith("warp-subdiv: internal error: ValueError: something inside")
    assert "WARP_SUBDIV_DEBUG=1" in lines[0] and "traceback" in lines[0]
    assert not (tmp_path / "x.obj").exists()
    monkeypatch.setenv("WARP_SUBDIV_DEBUG", "1")
    with pytest.raises(ValueError, match="something inside"):
        cli.main(args)


def test_input_errors_exit_2_with_the_flag_named(tmp_path, monkeypatch, capsys):
    """A SubdivInputError from the same place exits 2; errors about an option the command line set name its
    flag (the library's messages name the keyword)."""
    from warp_subdiv import cli
    from warp_subdiv.io import obj as objio
    from warp_subdiv.errors import SubdivInputError

    def bad(path):
        raise SubdivInputError(f"{path}: not a mesh")

    monkeypatch.setattr(objio, "read_obj", bad)
    assert cli.main(["refine", mesh_path("cube"), "-o", str(tmp_path / "x.obj"), "--levels", "1"]) == 2
    assert "error: " in capsys.readouterr().err
    monkeypatch.undo()
    for args, needle in ((["render", mesh_path("cube"), "-o", str(tmp_path / "x.png"), "--size", "12"], "--size '12'"),
                         (["render", mesh_path("cube"), "-o", str(tmp_path / "x.png"), "--device", "bogus"],
                          "--device bogus"),
                         (["refine", mesh_path("cube"), "-o", str(tmp_path / "x.obj"), "--levels", "1",
                           "--max-memory", "lots"], "--max-memory 'lots'")):
        assert cli.main(args) == 2
        lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warp-subdiv")]
        assert len(lines) == 1 and lines[0].startswith("warp-subdiv: error: ") and needle in lines[0], lines
    assert os.listdir(tmp_path) == []


def test_the_library_names_no_flags():
    """Messages of the library (every module but the CLI) name options by keyword, never by command-line flag:
    the CLI phrases them as flags where it reports."""
    import ast

    folder = os.path.join(ROOT, "warp_subdiv")
    for base, _, files in os.walk(folder):
        for name in files:
            path = os.path.join(base, name)
            if not name.endswith(".py") or path == os.path.join(folder, "cli.py"):
                continue
            tree = ast.parse(open(path, encoding="utf-8").read())
            docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                          if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                          and node.body and isinstance(node.body[0], ast.Expr)
                          and isinstance(node.body[0].value, ast.Constant)}
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                    assert not re.search(r"(^|[^\w-])--[a-z]", node.value), (path, node.lineno, node.value)


def test_semi_sharp_flag_help_says_what_it_does(capsys):
    """--semi-sharp-as-sharp makes semi-sharp tags infinitely sharp (by default they refine as semi-sharp)."""
    from warp_subdiv import cli

    assert cli.main(["refine", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "make semi-sharp creases and corners (0 < sharpness < 10) infinitely sharp, with a warning" in text
    assert "refusing" not in text


@pytest.mark.parametrize("args,needle", [
    (["refine", "{cube}", "-o", "{out}.usdz", "--levels", "1"],
     "{out}.usdz: cannot write .usdz: OBJ input is written as .obj, .usd, .usda or .usdc"),
    (["refine", "{scene}", "-o", "{out}.usdz", "--levels", "1"],
     "{out}.usdz: cannot write .usdz: USD input is written as .usd, .usda or .usdc"),
    (["refine", "{scene}", "-o", "{out}.obj", "--levels", "1"],
     "{out}.obj: cannot write .obj: USD input is written as .usd, .usda or .usdc"),
    (["tessellate", "{cube}", "-o", "{out}.ply", "--rate", "2"],
     "{out}.ply: cannot write .ply: OBJ input is written as .obj, .usd, .usda or .usdc"),
    (["tessellate", "{scene}", "-o", "{out}.usdz", "--rate", "2"],
     "{out}.usdz: cannot write .usdz: USD input is written as .usd, .usda or .usdc"),
    (["refine", "{cube}", "-o", "{out}", "--levels", "1"],
     "{out}: give the output an extension (.obj, .usd, .usda or .usdc)"),
    (["refine", "{out}.usdz", "-o", "{out}.usda", "--levels", "1"],
     "{out}.usdz: only .obj, .usd, .usda and .usdc input is supported"),
    (["tessellate", "{out}.usdz", "-o", "{out}.usda", "--rate", "2"],
     "{out}.usdz: only .obj, .usd, .usda and .usdc input is supported"),
])
def test_unsupported_file_types_say_whether_input_or_output(tmp_path, capsys, args, needle):
    """An output path of a type the command cannot write is refused as an output, with the types it can
    write for that input (not with the message about inputs, which named the wrong file's role)."""
    from warp_subdiv import cli

    values = dict(cube=mesh_path("cube"), scene=os.path.join(ROOT, "scenes", "animated.usda"),
                  out=str(tmp_path / "out"))
    assert cli.main([a.format(**values) for a in args]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warp-subdiv")]
    assert lines == ["warp-subdiv: error: " + needle.format(**values)]
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_written_obj_files_get_the_permissions_of_a_new_file(tmp_path, capsys, umask):
    """An OBJ output is readable as any new file is (0666 less the umask), as the USD outputs are: it is written
    to a temporary file, which only its owner may read, and renamed; a file it replaces keeps its mode."""
    from warp_subdiv import cli

    out = tmp_path / "cube.obj"
    old = os.umask(umask)
    try:
        assert cli.main(["refine", mesh_path("cube"), "-o", str(out), "--levels", "1", "--device", "cpu",
                         "--quiet"]) == 0, capsys.readouterr().err
        assert out.stat().st_mode & 0o7777 == 0o666 & ~umask
        out.chmod(0o604)
        assert cli.main(["refine", mesh_path("cube"), "-o", str(out), "--levels", "1", "--device", "cpu",
                         "--quiet"]) == 0, capsys.readouterr().err
        assert out.stat().st_mode & 0o7777 == 0o604
    finally:
        os.umask(old)
