"""Evaluation of a refinement's tables on a Warp device: the tables uploaded as device records, launches recorded and
replayed (CPU threads over row ranges, CUDA graphs), the level buffers, and device arrays of other frameworks wrapped
without a copy.

The evaluator applies index and stencil tables and the projections' displacement tables; it never sees the topology
or a rule.
"""
from .evaluator import Evaluated, Evaluator, _load_kernels, default_device, normal_control_for
from .evaluator import _load_kernels as load_kernels

__all__ = ["Evaluated", "Evaluator", "_load_kernels", "default_device", "load_kernels", "normal_control_for"]
