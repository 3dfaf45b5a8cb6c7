"""Evaluation of a refinement's tables on a Warp device: the tables uploaded as device records, launches recorded and
replayed (CPU threads over row ranges, CUDA graphs), the level buffers, and device arrays of other frameworks wrapped
without a copy.

The evaluator applies index and stencil tables and the projections' displacement tables; it never sees the topology
or a rule. Modules: ``records`` (the device records and their upload), ``launch`` (launchers, recorders, replayed
plans, the loaded kernel modules), ``dispatch`` (the kernels of each record kind), ``buffers`` (level buffers,
copies in and out), ``inputs`` and ``interop`` (checking a caller's host and device data), ``evaluator`` (the
:class:`Evaluator`).
"""
from .buffers import LevelBuffers, kernel_view
from .dispatch import apply, displace, limit_normals, limit_positions, refine_step
from .evaluator import Evaluated, Evaluator, default_device
from .inputs import host_rows, normal_control_for, shaped_rows, vertex_rows
from .interop import device_rows
from .launch import Launcher, load_kernels
from .records import (PRECISIONS, Displacement, ExplicitRows, LimitMasks, Projection, QuadStep, StencilStep, StepRecord,
                      TriangleStep, Uploader)

__all__ = ["PRECISIONS", "Displacement", "Evaluated", "Evaluator", "ExplicitRows", "Launcher", "LevelBuffers",
           "LimitMasks", "Projection", "QuadStep", "StencilStep", "StepRecord", "TriangleStep", "Uploader", "apply",
           "default_device", "device_rows", "displace", "host_rows", "kernel_view", "limit_normals", "limit_positions",
           "load_kernels", "normal_control_for", "refine_step", "shaped_rows", "vertex_rows"]
