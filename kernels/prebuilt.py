"""Kernel binaries compiled ahead of time, shipped in the package, loaded instead of compiling where they fit.

Warp compiles a kernel module on its first use in a process that finds no binary of it in Warp's kernel cache:
about 12 s for the modules of one refinement on a fresh machine. ``pip install`` therefore compiles the modules
once (``setup.py`` runs :func:`build` into the package's ``prebuilt/`` folder) and :func:`load` loads those
binaries directly (Warp's ``Module.load(binary_path=...)``), leaving Warp's kernel cache untouched.

A binary is used only where it fits, and nothing else changes where one does not: :func:`find` checks

* the Warp version, the operating system, the machine and the CPU target (Warp's CPU cache key: its LLVM, the
  target triple and, as Warp compiles for the host's instruction set, the CPU's features);
* the module's identity, Warp's hash of the kernels' source and compile options (a module edited after the
  build hashes differently);
* every file's SHA-256 against the manifest written at build time (a missing, truncated or corrupt file);
* on CUDA, that the device's architecture is at least the PTX's.

Where any check fails, or Warp cannot load the binary, :func:`load` returns False and the caller compiles the
module as Warp always does (:func:`warp_subdiv.evaluator.load_kernels`). Setting the environment variable
``WARP_SUBDIV_PREBUILT=0`` ignores the shipped binaries.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import json
import os
import shutil
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import warp as wp

#: The folder the package ships its binaries in (written at install; absent in a source checkout).
SHIPPED = Path(__file__).resolve().parent / "prebuilt"

#: The manifest in that folder: format, Warp version, CPU cache key and, per module and target, its files.
MANIFEST = "manifest.json"

#: The kernel modules compiled ahead of time: every module of this package with kernels.
MODULES = ("regular", "stencil", "projection", "convert", "limit", "adjoint", "render")

#: PTX architectures shipped for CUDA: Warp's default PTX target (the oldest architecture with all its
#: features); a newer GPU's driver translates it when the module loads.
PTX_ARCHS = (75,)

#: CPU launches run with one thread per block (Warp's CPU default); CUDA modules load in Warp's default variant.
CPU_BLOCK_DIM = 1

_FORMAT = 1


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _block_dim(module, device) -> int:
    return CPU_BLOCK_DIM if device.is_cpu else module.options["block_dim"]


def build(out_dir, cuda_archs=PTX_ARCHS, modules=MODULES, max_workers: int | None = None) -> dict:
    """Compile kernel ``modules`` (names of :data:`MODULES`) for this machine's CPU (and, where Warp's NVRTC is
    present, to PTX for ``cuda_archs``; no GPU or driver needed) into ``out_dir`` with a manifest; returns the
    manifest.

    The CPU binaries are those Warp itself compiles for a launch on this machine (the same options, so the same
    module hash), compiled in Warp's kernel cache (or taken from it where already there) and copied. Where no
    PTX can be compiled, the manifest has none (CUDA then compiles at run time)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    wp.init()
    cpu = wp.get_device("cpu")
    warp_modules = [wp.get_module(importlib.import_module(f"{__package__}.{name}").__name__) for name in modules]
    manifest = {"format": _FORMAT, "warp": wp.config.version, "cpu_key": wp.get_cpu_kernel_cache_key(),
                "modules": {m.name: {} for m in warp_modules}}
    workers = max_workers if max_workers is not None else min(len(warp_modules), os.cpu_count() or 1)
    wp.force_load(device=cpu, modules=warp_modules, block_dim=CPU_BLOCK_DIM, max_workers=workers)
    for m in warp_modules:
        binary = Path(m.load(cpu, block_dim=CPU_BLOCK_DIM).binary_path)
        ident = m.get_module_identifier(CPU_BLOCK_DIM)
        manifest["modules"][m.name]["cpu"] = _copy_target(out_dir, ident, binary, binary.parent / f"{ident}.meta")
    with tempfile.TemporaryDirectory(prefix="warp_subdiv_ptx_") as scratch, \
            ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        for arch in cuda_archs:  # the modules compiled at once, as Warp's force_load does
            jobs = {m.name: pool.submit(_build_ptx, out_dir, m, arch, scratch) for m in warp_modules}
            for name, job in jobs.items():
                try:
                    manifest["modules"][name][f"sm{arch}"] = job.result()
                except Exception as e:  # noqa: BLE001 (no NVRTC, or no PTX for it: CUDA compiles at run time)
                    print(f"warp-subdiv: no PTX for sm_{arch} of {name}: {e}")
    (out_dir / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True))
    return manifest


def _build_ptx(out_dir: Path, module, arch: int, scratch: str) -> dict:
    work = Path(scratch) / f"{module.name}_sm{arch}"
    (binary,) = wp.compile_aot_module(module, arch=arch, module_dir=work, use_ptx=True)
    ident = module.get_module_identifier(module.options["block_dim"])
    target = _copy_target(out_dir, ident, Path(binary), Path(binary).parent / f"{ident}.meta")
    target["arch"] = arch
    return target


def _copy_target(out_dir: Path, ident: str, binary: Path, meta: Path) -> dict:
    """Copy one target's binary and metadata into ``out_dir/ident/``; its manifest entry."""
    folder = out_dir / ident
    folder.mkdir(exist_ok=True)
    files = {}
    for kind, source in (("binary", binary), ("meta", meta)):
        shutil.copyfile(source, folder / source.name)
        files[kind] = f"{ident}/{source.name}"
    return {"id": ident, **files, "sha256": {files[k]: _sha256(folder / Path(files[k]).name) for k in files}}


@functools.lru_cache(maxsize=None)
def _manifest(directory: str) -> dict | None:
    try:
        manifest = json.loads((Path(directory) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(manifest, dict) or manifest.get("format") != _FORMAT:
        return None
    return manifest


def find(module, device, directory=None) -> tuple[Path, Path, int | None] | None:
    """(binary, metadata, CUDA architecture or None) of the shipped binary of kernel ``module`` (a Python
    module of this package) that fits ``device``, or None where none does (see the module's docstring)."""
    directory = Path(directory if directory is not None else SHIPPED)
    manifest = _manifest(str(directory))
    if manifest is None or manifest.get("warp") != wp.config.version:
        return None
    try:
        device = wp.get_device(device)
        warp_module = wp.get_module(module.__name__)
        targets = manifest["modules"].get(warp_module.name, {})
        if device.is_cpu:
            if manifest.get("cpu_key") != wp.get_cpu_kernel_cache_key():
                return None
            target = targets.get("cpu")
        else:
            fitting = [t for t in targets.values() if t.get("arch") is not None and t["arch"] <= device.arch]
            target = max(fitting, key=lambda t: t["arch"]) if fitting else None
        if target is None or target["id"] != warp_module.get_module_identifier(_block_dim(warp_module, device)):
            return None
        for name, digest in target["sha256"].items():
            if _sha256(directory / name) != digest:
                return None
        return directory / target["binary"], directory / target["meta"], target.get("arch")
    except Exception:  # noqa: BLE001 (a malformed manifest, or a Warp without these calls: no binary fits)
        return None


def load(module, device, directory=None) -> bool:
    """Load kernel ``module`` on ``device`` from its shipped binary where one fits (:func:`find`); False where
    none does or Warp cannot load it (the caller then compiles it as usual). Never raises for a bad binary."""
    if os.environ.get("WARP_SUBDIV_PREBUILT", "1") == "0":
        return False
    found = find(module, device, directory)
    if found is None:
        return False
    binary, meta, arch = found
    try:
        warp_module = wp.get_module(module.__name__)
        device = wp.get_device(device)
        warp_module.load(device, block_dim=_block_dim(warp_module, device), binary_path=binary, output_arch=arch,
                         meta_path=meta)
    except Exception:  # noqa: BLE001 (a binary Warp cannot load, whatever the reason: compiled instead)
        return False
    return True


def loaded_from(module, device) -> str | None:
    """The binary kernel ``module`` is loaded from on ``device`` (a shipped one or one in Warp's kernel cache),
    or None where it is not loaded."""
    warp_module = wp.get_module(module.__name__)
    device = wp.get_device(device)
    exec_ = warp_module.execs.get((device.context, _block_dim(warp_module, device)))
    return None if exec_ is None else exec_.binary_path
