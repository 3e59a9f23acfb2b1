"""The worker process of the equal-settings study (``equal_settings``): one configuration's
stepper (the engine, the engine through ``Simulation.run``, the yardstick kernel, numpy or Warp),
built, compiled and warmed up, then timed whenever the coordinator asks on stdin.

    python -m taichi_soft.bench.speed_worker '<JSON spec>'
"""
from __future__ import annotations

import taichi as ti

from ..sim.scene import load_scene
from ..sim.simulation import Simulation
from .machine_limits import thread_overlap
from ..timing import no_sync, time_one

REFERENCE_SCENE = ["terrain.kind=none", "body.0.initial_stretch=[1.05, 0.97, 1.0]"]
RUN_FPS = 30  # output frames per second of the "run" rows (the scene files' default)
REPEAT_SECONDS = 0.25  # work per timed repeat


class _Stepper:
    """One configuration inside a worker: ``reset()``, ``advance(k)``, ``sync()``, ``x()``."""

    def __init__(self, spec: dict):
        import numpy as np

        from .. import runtime
        from ..workarounds import cpu_threads

        kind, precision = spec["kind"], spec["precision"]
        init_kw = {"pin_threads": runtime.PIN_THREADS_CLI_DEFAULT}  # what the command line's runs get
        if spec.get("threads"):
            init_kw["cpu_max_num_threads"] = int(spec["threads"])
        if kind in ("engine", "run", "yardstick"):
            runtime.init(spec["arch"], precision, fast_math=spec["fast_math"], **init_kw)
        else:  # the model (numpy arrays, spring parameters) comes from the engine's builder
            runtime.init("cpu", precision)  # numpy and Warp: Taichi only builds their model
        # "run": the user's path, Simulation.run on the plane terrain (as `run` without a video)
        sets = REFERENCE_SCENE[1:] if kind == "run" else REFERENCE_SCENE
        scene = load_scene("plane", [f"body.0.n={spec['n']}", *sets])
        self.sim = Simulation(scene, integrator="semi_implicit_euler")
        self.springs = self.sim.model.n_springs
        self.evals = self.springs  # spring evaluations per step (a gather evaluates each twice)
        model, x0, v0, dt = self.sim.model, self.sim.model.x0_np, self.sim.model.v0_np, self.sim.dt
        real = np.float64 if precision == "f64" else np.float32
        self.kind = kind
        self.mode = ""
        if kind in ("engine", "run"):
            self.reset, self.advance, self.sync = self.sim.reset, self.sim.advance, ti.sync
            if kind == "run":
                self.advance = lambda k: self.sim.run(k * dt, RUN_FPS, progress=lambda done, total, s: None).steps
            self.x = lambda: self.sim.state.x.to_numpy()
            forces = self.sim.integrator.forces.strategy
            self.mode = ("serial" if self.sim.integrator._serial() else "parallel") + f", {forces}"
            if forces in ("gather", "stencil"):
                self.evals = 2 * self.springs
        elif kind == "yardstick":
            from .references import YardstickStepper

            ys = YardstickStepper(model, x0, v0, dt)
            # An explicit gather step like the engine's: the same placement of the pool (engine
            # steps get it from Simulation.advance; this kernel does not go through it).
            cpu_threads.place(True)
            self.reset, self.advance, self.sync = (lambda: ys.set(x0, v0)), ys.step, ti.sync
            self.x = lambda: ys.numpy()[0]
            self.mode, self.evals = "parallel, CSR gather", 2 * self.springs
        elif kind == "numpy":
            from .references import NumpyStepper

            nps = NumpyStepper(model, x0, v0, dt, real)

            def reset():
                nps.x[:] = x0
                nps.v[:] = v0
            self.reset, self.advance, self.sync, self.x = reset, nps.step, no_sync, (lambda: nps.x.copy())
        else:
            from .references import WarpStepper

            ws = WarpStepper(model, x0, v0, dt, precision, spec["arch"], fast_math=spec["fast_math"])

            def reset():
                ws.x.assign(np.asarray(x0, real))
                ws.v.assign(np.asarray(v0, real))
            self.reset, self.advance, self.sync, self.x = reset, ws.step, ws.sync, (lambda: ws.numpy()[0])

    def calibrate(self) -> int:
        """Warm up (compile), then the step count of about REPEAT_SECONDS of work."""
        self.advance(2)
        self.sync()
        k = 1
        while True:
            t = self.timed(k)
            if t > 0.05 or k >= 4096:
                t = min(t, self.timed(k), self.timed(k))  # a load spike must not shrink the chunk
                return max(1, min(20000, round(k * REPEAT_SECONDS / max(t, 1e-9))))
            k *= 4

    def timed(self, chunk: int, cpu: bool = False):
        """Wall seconds of ``chunk`` steps from the start state (and this process's CPU seconds)."""
        t = time_one(lambda: self.advance(chunk), 1, setup=self.reset, sync=self.sync)
        return (t.wall[0], t.cpu[0]) if cpu else t.wall[0]


def _worker_main():
    """Worker loop: one JSON spec as argv[1]; then commands on stdin, one JSON answer per line."""
    import json
    import sys

    import numpy as np

    spec = json.loads(sys.argv[1])
    out = sys.stdout
    sys.stdout = sys.stderr  # only the protocol goes to the real stdout
    try:
        st = _Stepper(spec)
        chunk = st.calibrate()
    except Exception as e:  # noqa: BLE001 - reported to the coordinator, which reports it
        print(json.dumps({"error": f"{type(e).__name__}: {e}"}), file=out, flush=True)
        return
    print(json.dumps({"chunk": chunk, "springs": st.springs, "evals": st.evals, "mode": st.mode}), file=out,
                     flush=True)
    for line in sys.stdin:
        cmd = line.split()
        if not cmd or cmd[0] == "quit":
            break
        if cmd[0] == "run":
            wall, used = st.timed(chunk, cpu=True)
            print(json.dumps({"s": wall, "cpu_s": used}), file=out, flush=True)
        elif cmd[0] == "overlap":  # overlap MS: thread_overlap of two MS-millisecond tasks, now
            print(json.dumps({"overlap": thread_overlap((float(cmd[1]),), repeats=5)[0]["overlap"]}), file=out,
                  flush=True)
        elif cmd[0] == "state":  # state STEPS PATH: the positions after STEPS steps from the start
            st.reset()
            st.advance(int(cmd[1]))
            st.sync()
            np.save(cmd[2], np.asarray(st.x(), np.float64))
            print(json.dumps({"ok": True}), file=out, flush=True)


if __name__ == "__main__":
    _worker_main()
