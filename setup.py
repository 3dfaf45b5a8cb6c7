"""Build step of the wheel: compile the Warp kernel modules ahead of time into the package (everything else about
the package is declared in pyproject.toml).

After the ordinary ``build_py`` copied the sources, the kernels are compiled for this machine's CPU (and to PTX
for CUDA, where Warp's NVRTC is present: no GPU needed) into ``warp_subdiv/kernels/prebuilt/`` of the build, by
:func:`warp_subdiv.kernels.prebuilt.build` run in a child process, so that the first refinement after
``pip install .`` loads binaries instead of compiling (about 12 s). The step never fails the install: where it
cannot run (no Warp in the build environment, a compile error), the package ships no binaries and compiles at
first use as before. ``WARP_SUBDIV_PREBUILD=0`` skips it; editable installs skip it too.
"""
import os
import shutil
import subprocess
import sys
import tempfile

from setuptools import setup
from setuptools.command.build_py import build_py

# The child imports warp_subdiv.kernels from the build folder under a bare parent package: compiling kernels
# needs Warp only, not the package's other dependencies (numpy, usd-core), which the build environment lacks.
_CHILD = """
import os, sys, types
lib = sys.argv[1]
parent = types.ModuleType("warp_subdiv")
parent.__path__ = [os.path.join(lib, "warp_subdiv")]
sys.modules["warp_subdiv"] = parent
import warp as wp
wp.config.quiet = True
from warp_subdiv.kernels import prebuilt
prebuilt.build(sys.argv[2])
"""


class BuildPyWithKernels(build_py):
    """``build_py``, then the kernel modules compiled into the build (see the module's docstring)."""

    def run(self):
        super().run()
        out = os.path.join(self.build_lib, "warp_subdiv", "kernels", "prebuilt")
        shutil.rmtree(out, ignore_errors=True)  # nothing left over from an earlier build in the same folder
        if getattr(self, "editable_mode", False) or os.environ.get("WARP_SUBDIV_PREBUILD", "1") == "0":
            return
        with tempfile.TemporaryDirectory(prefix="warp_subdiv_cache_") as cache:
            env = dict(os.environ, WARP_CACHE_PATH=cache, PYTHONDONTWRITEBYTECODE="1")
            try:
                subprocess.run([sys.executable, "-c", _CHILD, os.path.abspath(self.build_lib), os.path.abspath(out)],
                               env=env, check=True, timeout=1800)
            except (OSError, subprocess.SubprocessError) as e:
                shutil.rmtree(out, ignore_errors=True)
                print(f"warp-subdiv: kernels not compiled ahead of time ({e}); they compile on first use",
                      file=sys.stderr)


setup(cmdclass={"build_py": BuildPyWithKernels})
