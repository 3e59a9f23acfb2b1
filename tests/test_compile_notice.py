"""The command line says on stderr that it is compiling while a kernel's first launch is long, and
stays silent when first launches are quick (compile_notice.py)."""
import os
import subprocess
import sys

from conftest import ROOT

PROBE = """
import sys, time
import taichi as ti
from taichi_soft import compile_notice, runtime
runtime.init("cpu", "f64")
compile_notice.THRESHOLD_S = {threshold}
compile_notice.install("CACHE")
compile_notice.watch()
x = ti.field(float, ())

@ti.kernel
def spin(n: ti.i64):
    ti.loop_config(serialize=True)
    for i in range(n):
        x[None] = ti.sin(x[None] + 1e-9 * i)

start = time.perf_counter()
spin({iterations})
print("first launch took", time.perf_counter() - start, file=sys.stderr, flush=True)
compile_notice.say_summary()
"""


def probe(tmp_path, threshold, iterations):
    script = tmp_path / "probe.py"  # Taichi reads a kernel's source from its file
    script.write_text(PROBE.format(threshold=threshold, iterations=iterations))
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_a_long_first_launch_is_said_while_it_runs_and_timed_at_the_end(tmp_path):
    r = probe(tmp_path, 1, 400_000_000)  # a first launch of several seconds
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if not line.startswith("[Taichi]")]
    notice = next(k for k, line in enumerate(lines) if line.startswith("compiling Taichi kernels"))
    took = next(k for k, line in enumerate(lines) if line.startswith("first launch took"))
    assert float(lines[took].split()[-1]) > 1.0
    assert notice < took, lines  # said during the launch, not after it
    assert "kernel cache CACHE" in lines[notice]
    assert lines[-1].startswith("Taichi kernels: 1 first launches took") and "later runs" in lines[-1]


def test_quick_first_launches_say_nothing(tmp_path):
    r = probe(tmp_path, 30, 1000)
    assert r.returncode == 0, r.stderr
    assert "compiling" not in r.stderr and "Taichi kernels:" not in r.stderr, r.stderr
