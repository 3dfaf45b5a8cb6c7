"""warp-subdiv on USD files as a user runs it: subprocesses for success and the user errors of the issue
(exit 2, one line on stderr, no traceback, no output file), started together so that the file costs about
as much as its slowest run; further errors, info and options through cli.main in this process."""
import os
import subprocess
import sys

import numpy as np
import pytest
from pxr import Usd, UsdGeom, Vt

from test_usd_support import ROOT, SCENES_DIR, digest, grid, write_mesh

SCENE = os.path.join(SCENES_DIR, "concave_corner.usda")
SCENE_DIGEST = digest(SCENE)  # the input, before any run: runs only ever read it
ANIMATED = os.path.join(SCENES_DIR, "animated.usda")


def start(*args, cwd=None):
    env = dict(os.environ)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.Popen([sys.executable, "-m", "warp_subdiv", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd, env=env)


def finish(proc):
    out, err = proc.communicate(timeout=180)
    return proc.returncode, out, err


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("cli")


def _bad_files(folder):
    pts, counts, idx = grid(2, 2)
    broken = write_mesh(folder / "broken.usda", pts, counts, idx[:-1] + [42], prim="/World/Broken")
    text = folder / "notusd.usda"
    text.write_text("this is not USD\n")
    blocker = folder / "blocker"
    blocker.write_text("a file where a folder should be\n")
    return broken, text, blocker


ERRORS = {
    # name: (arguments, expected text in the error line, output that must not exist)
    "bad path": (["refine", "{work}/missing.usda", "-o", "{work}/o1.usda", "--levels", "1"], "no such file", "o1.usda"),
    "not usd": (["refine", "{text}", "-o", "{work}/o2.usda", "--levels", "1"], "cannot open as USD", "o2.usda"),
    "not a mesh": (["refine", ANIMATED, "-o", "{work}/o3.usda", "--levels", "1", "--prim", "/World/Looks"],
                   "/World/Looks is not a mesh and holds no meshes", "o3.usda"),
    "broken topology": (["refine", "{broken}", "-o", "{work}/o5.usda", "--levels", "1"],
                        "/World/Broken: faceVertexIndices: face 3 corner 3 refers to vertex 42", "o5.usda"),
    "memory guard": (["refine", SCENE, "-o", "{work}/o6.usda", "--levels", "7", "--max-memory", "64M"],
                     "more than --max-memory 64.0 MiB", "o6.usda"),
    "unwritable": (["refine", SCENE, "-o", "{blocker}/o7.usda", "--levels", "1", "--device", "cpu"],
                   "cannot write there", None),
}

IN_PROCESS = {
    "no prim": (["refine", ANIMATED, "-o", "{work}/p1.usda", "--levels", "1", "--prim", "/World/Nope"],
                "no prim at /World/Nope", "p1.usda"),
    "bad frames": (["refine", ANIMATED, "-o", "{work}/p2.usda", "--levels", "1", "--frames", "9:3"],
                   "--frames '9:3': the start is after the end", "p2.usda"),
    "usage": (["refine", SCENE, "--levels", "1"], "the following arguments are required: -o/--output", None),
    "obj out": (["refine", SCENE, "-o", "{work}/p3.obj", "--levels", "1"], "USD input is written as .usd", "p3.obj"),
    "negative levels": (["refine", SCENE, "-o", "{work}/p4.usda", "--levels", "-2"], "--levels must be >= 0", "p4.usda"),
    "bad size": (["refine", SCENE, "-o", "{work}/p5.usda", "--levels", "1", "--max-memory", "lots"],
                 "--max-memory 'lots'", "p5.usda"),
    "output is input": (["refine", SCENE, "-o", SCENE, "--levels", "1"], "the input reads this file", None),
    "flatten all variants": (["refine", SCENE, "-o", "{work}/p6.usda", "--levels", "1", "--all-variants", "--flatten"],
                             "--flatten cannot be combined", "p6.usda"),
}


REFINED = "refined/concave_corner_L3.usdc"


@pytest.fixture(scope="module")
def error_runs(work):
    """Every subprocess of this file, started at once: the error cases and one successful refinement."""
    broken, text, blocker = _bad_files(work)
    procs = {}
    for name, (args, _, _) in ERRORS.items():
        args = [a.format(work=work, broken=broken, text=text, blocker=blocker) for a in args]
        procs[name] = start(*args, cwd=work)
    procs["success"] = start("refine", SCENE, "-o", work / REFINED, "--levels", "3", "--device", "cpu")
    return {name: finish(p) for name, p in procs.items()}


@pytest.mark.parametrize("name", sorted(ERRORS))
def test_user_errors_exit_2_with_one_line_and_no_output(work, error_runs, name):
    code, out, err = error_runs[name]
    _, needle, output = ERRORS[name]
    assert digest(SCENE) == SCENE_DIGEST
    assert code == 2, (code, err)
    lines = [line for line in err.splitlines() if line.startswith("warp-subdiv")]
    assert len(lines) == 1 and lines[0].startswith("warp-subdiv: error: ") and needle in lines[0], err
    assert "Traceback" not in err
    if output:
        assert not (work / output).exists()
    assert not [f for f in os.listdir(work) if f.startswith(".warp-subdiv-")]  # no temporary left behind
    assert not os.path.isdir(work / "blocker")


def one_error_line(err):
    lines = [line for line in err.splitlines() if line.startswith("warp-subdiv")]
    assert len(lines) == 1 and lines[0].startswith("warp-subdiv: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("name", sorted(IN_PROCESS))
def test_more_user_errors(work, capsys, name):
    from warp_subdiv import cli

    args, needle, output = IN_PROCESS[name]
    before = digest(SCENE)
    code = cli.main([a.format(work=work) for a in args])
    err = capsys.readouterr().err
    assert code == 2 and needle in one_error_line(err), err
    if output:
        assert not (work / output).exists()
    assert digest(SCENE) == before


def test_refine(work, error_runs):
    out = work / REFINED
    code, stdout, err = error_runs["success"]
    assert code == 0, err
    assert "Traceback" not in err and not [line for line in err.splitlines() if "error" in line]
    # the summary table: one row per mesh, then the totals
    for prim in ("/World/PiecewiseSmooth/LPlate", "/World/PiecewiseSmooth/HoledPlate", "/World/OpenSubdiv/LPlate",
                 "/World/OpenSubdiv/HoledPlate"):
        assert any(line.strip().startswith(prim) for line in stdout.splitlines()), stdout
    assert "total: 4 meshes, faces 72 -> 4608" in stdout
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/OpenSubdiv/HoledPlate"))
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == 24 * 64
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none"


def test_info(capsys):
    from warp_subdiv import cli

    code = cli.main(["info", ANIMATED, "--levels", "2"])
    istdout = capsys.readouterr().out
    # the mesh, its tags, primvars, time samples and predicted sizes per level
    assert code == 0
    for needle in ("/World/Animated/Plate", "4 crease edges, 1 corners", "points have 24 samples",
                   "st (faceVarying texCoord2f[], indexed)", "velocities: 24 samples"):
        assert needle in istdout, istdout
    table = [line.split() for line in istdout.splitlines() if line.strip()[:1].isdigit()]
    assert [(row[0], row[1]) for row in table] == [("1", "48"), ("2", "192")]


def test_semi_sharp_refines_and_the_flag_makes_it_sharp(work, capsys):
    from warp_subdiv import cli

    pts, counts, idx = grid(2, 2)
    src = write_mesh(work / "semi.usda", pts, counts, idx, attrs={
        "creaseIndices": Vt.IntArray([1, 4, 7]), "creaseLengths": Vt.IntArray([3]),
        "creaseSharpnesses": Vt.FloatArray([2.0])})
    code_a = cli.main(["refine", src, "-o", str(work / "semi_a.usda"), "--levels", "1", "--device", "cpu"])
    err_a = capsys.readouterr().err
    assert code_a == 0, err_a  # semi-sharp creases refine as such
    code_b = cli.main(["refine", src, "-o", str(work / "semi_b.usda"), "--levels", "1", "--device", "cpu",
                       "--semi-sharp-as-sharp", "--quiet"])
    captured = capsys.readouterr()
    assert code_b == 0 and captured.out == ""
    assert "warning: /World/Mesh: 2 semi-sharp crease edges / corners are treated as infinitely" in captured.err
    stage = Usd.Stage.Open(str(work / "semi_b.usda"))
    assert np.asarray(stage.GetPrimAtPath("/World/Mesh").GetAttribute("points").Get()).shape == (25, 3)


def test_obj_input_can_be_written_as_usd(work, capsys):
    from warp_subdiv import cli

    out = work / "lshape.usda"
    code = cli.main(["refine", os.path.join(SCENES_DIR, "lshape_concave.obj"), "-o", str(out), "--levels", "2",
                     "--device", "cpu"])
    assert code == 0, capsys.readouterr().err
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim())
    ok, why = UsdGeom.Mesh.ValidateTopology(mesh.GetFaceVertexIndicesAttr().Get(),
                                            mesh.GetFaceVertexCountsAttr().Get(), len(mesh.GetPointsAttr().Get()))
    assert ok, why
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none" and len(mesh.GetFaceVertexCountsAttr().Get()) == 8 * 16


def _negative_time_stage(path):
    """A grid whose points are sampled at negative time codes only (-12, -8, -4)."""
    pts, counts, idx = grid(2, 2)
    return write_mesh(path, pts, counts, idx, time_points={t: pts + [0.0, 0.0, 0.1 * t] for t in (-12, -8, -4)})


@pytest.mark.parametrize("spelling", ["separate", "joined"])
def test_negative_frame_ranges_parse_as_values(work, capsys, spelling):
    """A frame range that starts with a minus sign is the value of --frames, given as `--frames -10:-5` as
    well as `--frames=-10:-5`: argparse alone takes a word that begins with '-' and is not a plain number
    for an option, and the user was told --frames expected one argument."""
    from warp_subdiv import cli

    src = _negative_time_stage(work / f"negative_{spelling}.usda")
    for frames, times in (("-10:-5", [-10.0, -8.0, -5.0]), ("-9:", [-9.0, -8.0, -4.0])):
        out = work / f"negative_{spelling}_{frames.replace(':', '_')}.usda"
        flag = ["--frames", frames] if spelling == "separate" else [f"--frames={frames}"]
        code = cli.main(["refine", str(src), "-o", str(out), "--levels", "1", "--device", "cpu", "--quiet", *flag])
        assert code == 0, capsys.readouterr().err
        stage = Usd.Stage.Open(str(out))
        assert stage.GetPrimAtPath("/World/Mesh").GetAttribute("points").GetTimeSamples() == times


@pytest.mark.parametrize("args,name,value", [
    (["refine", "in.usda", "-o", "out.usda", "--levels", "1", "--frames", "-24:"], "frames", "-24:"),
    (["refine", "in.usda", "-o", "out.usda", "--levels", "1", "--frames", "-10:-5"], "frames", "-10:-5"),
    (["tessellate", "in.usda", "-o", "out.usda", "--rate", "2", "--frames", "-10:-5"], "frames", "-10:-5"),
    (["render", "in.usda", "-o", "out.png", "--time", "-1e3"], "time", "-1e3"),
    (["render", "in.usda", "-o", "out.png", "--view", "-60", "-1e1"], "view", [-60.0, -10.0]),
])
def test_options_take_values_that_begin_with_a_minus(args, name, value):
    """Every option whose value may be negative (frame ranges, time codes, angles) takes it after a space."""
    from warp_subdiv import cli

    assert getattr(cli._parser().parse_args(args), name) == value
