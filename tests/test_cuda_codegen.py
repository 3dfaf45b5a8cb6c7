"""CUDA code generation is checked on machines without a GPU: every Warp module compiles to PTX."""
import importlib
import pkgutil

import pytest
import warp as wp

import warp_subdiv.kernels as kernels


def kernel_modules():
    """The modules of warp_subdiv.kernels that define kernels (layout.py holds only the functions the kernels
    share; Warp compiles them into every module that uses them)."""
    out = []
    for m in pkgutil.iter_modules(kernels.__path__):
        name = f"warp_subdiv.kernels.{m.name}"
        if any(isinstance(k, wp.Kernel) for k in vars(importlib.import_module(name)).values()):
            out.append(name)
    return out


@pytest.mark.parametrize("name", kernel_modules())
def test_module_compiles_to_ptx(name, tmp_path):
    module = importlib.import_module(name)
    wp.init()
    try:
        paths = wp.compile_aot_module(module, arch=[75, 86, 90], module_dir=tmp_path, use_ptx=True)
    except RuntimeError as exc:  # pragma: no cover - only where Warp ships without NVRTC
        if "NVRTC" in str(exc) or "CUDA" in str(exc) and "not" in str(exc):
            pytest.skip(f"Warp cannot compile CUDA here: {exc}")
        raise
    ptx = [p for p in paths if str(p).endswith(".ptx")]
    assert len(ptx) == 3, paths
    names = [k.key for k in vars(module).values() if isinstance(k, wp.Kernel)]
    assert names
    for p in ptx:
        text = p.read_text()
        assert ".entry" in text
        for name in names:  # every kernel of the module has a CUDA entry point
            assert name in text, (name, p)
