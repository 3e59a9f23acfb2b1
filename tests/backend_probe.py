"""Simulation cases run on one Taichi backend after another, in one child process.

Taichi's backend is chosen once per process (``ti.init``), and a driver crash must not take pytest
down, so the cases run in a child: for each backend in turn, each case on a runtime started for it
(f32; Vulkan has no f64 here). ``runtime.init`` refuses a backend Taichi would replace by the CPU,
and the child reports the arch Taichi really started, so a fallback fails the caller's asserts
instead of passing as two CPU runs.

A case is a dict: ``scene``, ``sets`` (``--set`` overrides), ``integrator``, ``dt`` [s], ``steps``,
``options`` (the integrator's options on every backend) and ``options_by_arch`` (arch -> options
laid over them, e.g. the CPU's launch mode forced to what a GPU picks by itself) ``fast_math``
(the runtime's, default false) and ``bad_velocity`` (a value, such as "nan", given to one
particle's velocity before the first step, for the divergence check). Per backend and
case the child returns the arch asked for and the one started, the force strategy (None for the
implicit solvers), the resolved options, the integrator's ``stats()``, the final and initial
positions [m], whether the run diverged, and the wall time [s] of the set-up (the runtime's start
and the simulation's construction) and of the steps (their compile included).
"""
import json
import os
import subprocess
import sys

from conftest import ROOT

PROBE = """
import dataclasses, json, sys, time
import taichi as ti
from taichi_soft import runtime
from taichi_soft.sim.scene import load_scene
from taichi_soft.sim.simulation import Simulation

cases, archs = json.loads(sys.argv[1]), sys.argv[2:]
out = {}
for arch in archs:
    out[arch] = []
    for case in cases:
        t0 = time.perf_counter()
        runtime.init(arch, "f32", fast_math=case.get("fast_math", False))
        options = {**case.get("options", {}), **case.get("options_by_arch", {}).get(arch, {})}
        sim = Simulation(load_scene(case.get("scene", "plane"), case.get("sets", [])), integrator=case["integrator"],
                         dt=case["dt"], options=options)
        if case.get("bad_velocity") is not None:
            x, v = sim.state.numpy()
            v[5, 1] = float(case["bad_velocity"])
            sim.state.set(x, v)
        t1 = time.perf_counter()
        done = sim.advance(case["steps"])
        t2 = time.perf_counter()
        integ = sim.integrator
        out[arch].append({
            "arch": runtime.current()["arch"], "started": ti.lang.impl.current_cfg().arch.name,
            "strategy": integ.forces.strategy if integ.forces is not None else None,
            "options": dataclasses.asdict(integ.options), "stats": integ.stats(), "steps": done,
            "diverged": bool(integ.diverged), "x": sim.state.numpy()[0].tolist(), "x0": sim.model.x0_np.tolist(),
            "seconds": {"set_up": t1 - t0, "advance": t2 - t1}})
        ti.reset()
print(json.dumps(out))
"""


def run_on_backends(cases: list, archs: tuple, timeout: float = 300) -> dict:
    """``{arch: [result per case, in order]}`` for ``cases`` run on each of ``archs`` (see the module
    docstring); a child that fails raises ``AssertionError`` with the end of its stderr."""
    r = subprocess.run([sys.executable, "-c", PROBE, json.dumps(cases), *archs], capture_output=True, text=True,
                       cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=timeout)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])
