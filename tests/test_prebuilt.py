"""Kernel binaries compiled ahead of time (warp_subdiv.kernels.prebuilt): used where they fit, with no compile and
Warp's kernel cache left empty; refused where they do not fit (another Warp, another CPU, an edited module, a
missing or corrupt file), the module then compiled as usual with bitwise the same results."""
import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import warp as wp

import warp_subdiv as ws
from warp_subdiv.io.obj import read_obj
from warp_subdiv.kernels import convert, prebuilt, projection, regular, stencil
from conftest import mesh_path

from test_cuda_codegen import kernel_modules

#: The modules a CPU refinement loads (warp_subdiv.evaluator.evaluation_kernels).
EVALUATION = ("regular", "stencil", "projection", "convert")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    """The evaluation modules built as the install builds them (CPU only: PTX is test_cuda_codegen's)."""
    out = tmp_path_factory.mktemp("prebuilt")
    prebuilt.build(out, cuda_archs=(), modules=EVALUATION)
    return out


def copy_of(shipped, tmp_path):
    out = tmp_path / "prebuilt"
    shutil.copytree(shipped, out)
    return out


def edit_manifest(folder, edit):
    manifest = json.loads((folder / prebuilt.MANIFEST).read_text())
    edit(manifest)
    (folder / prebuilt.MANIFEST).write_text(json.dumps(manifest))


def cpu_target(manifest, module):
    return manifest["modules"][module.__name__]["cpu"]


def refine_in_child(folder, cache):
    """Refine the cube at level 2 in a new process whose kernels come from ``folder`` where they fit, with Warp's
    kernel cache ``cache``; (points, {module: binary it loaded from})."""
    code = f"""
import json, sys
import numpy as np
import warp as wp
wp.config.quiet = True
from pathlib import Path
from warp_subdiv.kernels import prebuilt
prebuilt.SHIPPED = Path({str(folder)!r})
import warp_subdiv as ws
from warp_subdiv.io.obj import read_obj
from warp_subdiv.kernels import convert, projection, regular, stencil
points = ws.refine(read_obj({mesh_path("cube")!r}).mesh, 2, device="cpu", threads=1).points
np.save(sys.argv[1], points)
print(json.dumps({{m.__name__: prebuilt.loaded_from(m, "cpu") for m in (regular, stencil, projection, convert)}}))
"""
    out = folder.parent / "points.npy"
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("WARP_SUBDIV_PREBUILT", None)
    if cache is not None:
        env["WARP_CACHE_PATH"] = str(cache)
    run = subprocess.run([sys.executable, "-c", code, str(out)], env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr
    return np.load(out), json.loads(run.stdout.strip().splitlines()[-1])


def reference_points():
    return ws.refine(read_obj(mesh_path("cube")).mesh, 2, device="cpu", threads=1).points


def test_every_kernel_module_is_built_ahead():
    assert {f"warp_subdiv.kernels.{m}" for m in prebuilt.MODULES} == set(kernel_modules())


def test_fitting_binaries_load_with_no_compile(shipped, tmp_path):
    cache = tmp_path / "empty_cache"
    points, sources = refine_in_child(shipped, cache)
    assert all(path is not None and path.startswith(str(shipped)) for path in sources.values()), sources
    # nothing compiled: Warp wrote no module into its (new) kernel cache
    compiled = [p for p in cache.rglob("wp_*")]
    assert compiled == []
    np.testing.assert_array_equal(points, reference_points())


def test_corrupt_binaries_fall_back_to_compiling(shipped, tmp_path):
    folder = copy_of(shipped, tmp_path)
    manifest = json.loads((folder / prebuilt.MANIFEST).read_text())
    # stencil: bytes changed after the build (its checksum no longer matches)
    binary = folder / cpu_target(manifest, stencil)["binary"]
    data = bytearray(binary.read_bytes())
    data[len(data) // 2] ^= 0xFF
    binary.write_bytes(bytes(data))
    # convert: a file Warp cannot load, though its checksum matches
    target = cpu_target(manifest, convert)
    garbage = folder / target["binary"]
    garbage.write_bytes(b"not an object file" * 8)
    target["sha256"][target["binary"]] = hashlib.sha256(garbage.read_bytes()).hexdigest()
    # projection: its binary missing
    (folder / cpu_target(manifest, projection)["binary"]).unlink()
    (folder / prebuilt.MANIFEST).write_text(json.dumps(manifest))

    points, sources = refine_in_child(folder, None)  # Warp's own cache: the fallback compiles (or reuses) there
    for module in (stencil, convert, projection):
        assert sources[module.__name__] is not None and not sources[module.__name__].startswith(str(folder))
    assert sources[regular.__name__].startswith(str(folder))
    np.testing.assert_array_equal(points, reference_points())


@pytest.mark.parametrize("mismatch", ["warp version", "cpu", "module edited", "missing file", "checksum",
                                      "manifest unreadable", "manifest missing", "other format"])
def test_binaries_that_do_not_fit_are_refused(shipped, tmp_path, mismatch):
    folder = copy_of(shipped, tmp_path)
    assert prebuilt.find(stencil, "cpu", folder) is not None  # fits as built
    folder = copy_of(shipped, tmp_path / "edited")  # a new folder: manifests are read once per folder
    manifest = json.loads((folder / prebuilt.MANIFEST).read_text())
    target = cpu_target(manifest, stencil)
    if mismatch == "warp version":
        edit_manifest(folder, lambda m: m.update(warp="0.0.1"))
    elif mismatch == "cpu":  # another CPU (instruction set), LLVM or platform: another cache key
        edit_manifest(folder, lambda m: m.update(cpu_key=m["cpu_key"] + "0"))
    elif mismatch == "module edited":  # the kernels' source or options changed since the build
        edit_manifest(folder, lambda m: cpu_target(m, stencil).update(id=target["id"][:-1] + "x"))
    elif mismatch == "missing file":
        (folder / target["meta"]).unlink()
    elif mismatch == "checksum":
        (folder / target["binary"]).write_bytes((folder / target["binary"]).read_bytes()[:-1])
    elif mismatch == "manifest unreadable":
        (folder / prebuilt.MANIFEST).write_text("{not json")
    elif mismatch == "manifest missing":
        (folder / prebuilt.MANIFEST).unlink()
    else:
        edit_manifest(folder, lambda m: m.update(format=m["format"] + 1))
    assert prebuilt.find(stencil, "cpu", folder) is None
    assert prebuilt.load(stencil, "cpu", folder) is False


def test_switched_off_by_the_environment(shipped, monkeypatch):
    monkeypatch.setenv("WARP_SUBDIV_PREBUILT", "0")
    assert prebuilt.find(stencil, "cpu", shipped) is not None
    assert prebuilt.load(stencil, "cpu", shipped) is False


def test_no_ptx_is_used_on_the_cpu_and_no_cpu_binary_on_cuda(shipped):
    manifest = json.loads((shipped / prebuilt.MANIFEST).read_text())
    assert set(manifest["modules"][stencil.__name__]) == {"cpu"}
    if wp.get_cuda_device_count() > 0:
        assert prebuilt.find(stencil, "cuda:0", shipped) is None
