"""The benchmarks' small configurations run as smoke tests (no timing assertions): the scripts keep working."""
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize("script", ["bench_core.py", "bench_peers.py", "bench_gpu.py", "bench_batch.py",
                                    "bench_skinning.py"])
def test_benchmark_quick_mode_runs(script, tmp_path):
    """Each script's --quick mode runs to the end, prints a Markdown table and writes its JSON (bench_gpu.py on
    CUDA where present, else on the CPU)."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = tmp_path / "bench.json"
    res = subprocess.run([sys.executable, os.path.join(ROOT, "bench", script), "--quick", "--json", str(out)],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert "|" in res.stdout  # a Markdown table was printed
    assert out.exists() and out.stat().st_size > 0
