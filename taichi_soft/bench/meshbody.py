"""Mesh-body goals (``python main.py bench mesh``): building a 20^3-lattice body from a
100k-triangle mesh, and a rendered frame of such a body against a cube's.

* build: ``meshbody.mesh_lattice`` from the OBJ file on disk (read, close check, point-in-mesh
  test, springs, components, embedding weights), the cache emptied before each repeat; goal
  <= 2 s.
* frame: ``render`` (surface update on the device, lighting, draw, read-back) at 1280x720 of a
  torus mesh body (102,400 triangles, n = 20) and of a 20^3 cube on the plane, after a warm-up,
  interleaved, medians over repeats, with each renderer (taichi, and ggui where Vulkan works);
  goal: mesh frame <= 1.5x the cube's.

The torus is made by trimesh (48 x 24 sections scaled up to 320 x 160), written to a temporary
folder. Timings are wall clock on whatever machine runs this; the report says which and its load.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import UserError
from ..timing import Candidate, no_sync, time_candidates, time_one

N = 20
RESOLUTION = (1280, 720)


def _torus(path: Path, major: int = 320, minor: int = 160) -> int:
    import trimesh

    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=major, minor_sections=minor)
    mesh.export(path)
    return len(mesh.faces)


def measure_build(path: Path, repeats: int) -> dict:
    """Median and all wall times [s] of building the n = 20 body from ``path``, cache emptied."""
    from ..sim import meshbody

    t = time_one(lambda: meshbody.mesh_lattice(path, N, size=4.0), repeats, setup=meshbody._cached.cache_clear,
                 sync=no_sync)  # numpy work, no kernels in flight
    m = t.last
    # CPU seconds as well: on a shared, overloaded machine the wall time mostly measures the wait.
    return {"median_s": t.median, "samples_s": t.wall, "cpu_median_s": t.cpu_median,
            "particles": m.n_particles, "springs": m.n_springs, "lattice": list(m.grid.shape)}


def measure_frames(path: Path, repeats: int, kind: str) -> dict:
    """Median render times [ms] of the mesh body and the cube (interleaved) and their ratio, with
    the ``kind`` renderer (``ggui`` or ``taichi``, ``render/choose.py``)."""
    from ..render.camera import scene_camera
    from ..render.choose import make_renderer
    from ..render.renderer import SimulationView
    from ..sim.scene import scene_from_dict
    from ..sim.simulation import Simulation

    plane = {"kind": "plane", "point": [0, -1, 0], "normal": [0, 1, 0]}
    bodies = {"cube": {"n": N, "size": 4.0, "center": [0.0, 3.0, 0.0]},
              "mesh": {"shape": "mesh", "mesh": str(path), "n": N, "size": 4.0, "center": [0.0, 3.0, 0.0]}}
    renderer = make_renderer(*RESOLUTION, kind=kind)
    views, cams = {}, {}
    try:
        for name, body in bodies.items():
            scene = scene_from_dict({"body": [body], "terrain": plane})
            sim = Simulation(scene)
            views[name] = SimulationView(sim)
            cams[name] = scene_camera(scene.data, RESOLUTION[0] / RESOLUTION[1], False, 0.0)
        # interleaved in a fixed order, medians; warm-up: kernel compiles, GGUI pipelines
        frame = {name: Candidate(lambda v=views[name], c=cams[name]: renderer.render(v, c),
                                 warmup=lambda v=views[name], c=cams[name]: [renderer.render(v, c) for _ in range(3)])
                 for name in bodies}
        timings = time_candidates(frame, repeats, rotate=False)
    finally:
        renderer.close()
    med = {name: 1000 * t.median for name, t in timings.items()}
    return {"cube_ms": med["cube"], "mesh_ms": med["mesh"], "ratio": med["mesh"] / med["cube"],
            "surface_triangles": {name: v.surface.n_triangles for name, v in views.items()}}


def run(repeats: int = 5, frames: int = 20) -> dict:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "torus100k.obj"
        triangles = _torus(path)
        build = measure_build(path, repeats)
        frame = {}
        for kind in ("taichi", "ggui"):
            try:
                frame[kind] = measure_frames(path, frames, kind)
            except UserError as e:  # no Vulkan device for ggui: say so in the report
                frame[kind] = {"error": str(e)}
    return {"triangles": triangles, "build": build, "frame": frame, "load": os.getloadavg(),
            "cpus": os.cpu_count()}


def write_report(result: dict, out: Path) -> Path:
    """MESH.md in ``out``: the two goals, measured."""
    b = result["build"]
    load = ", ".join(f"{x:.1f}" for x in result["load"])
    rows = []
    for kind, f in result["frame"].items():
        if "error" in f:
            rows.append(f"| render a frame at {RESOLUTION[0]}x{RESOLUTION[1]} ({kind} renderer) | not measured: {f['error']} | <= 1.5x |")
        else:
            rows.append(f"| render a frame at {RESOLUTION[0]}x{RESOLUTION[1]} ({kind} renderer): that body "
                        f"({f['surface_triangles']['mesh']:,} surface triangles) vs a {N}^3 cube "
                        f"({f['surface_triangles']['cube']:,}) | {f['mesh_ms']:.1f} ms vs {f['cube_ms']:.1f} ms: "
                        f"{f['ratio']:.2f}x | <= 1.5x |")
    frame_rows = "\n".join(rows)
    text = f"""# Mesh bodies: build time and frame cost

Command: `python main.py bench mesh` ({result['cpus']} CPUs, load average {load} when it ended;
a shared machine makes these numbers noisy).

| goal | measured | target |
| --- | --- | --- |
| build a {N}^3-lattice body ({'x'.join(map(str, b['lattice']))} points, {b['particles']} particles, {b['springs']} springs) from a {result['triangles']:,}-triangle torus OBJ | {b['median_s']:.2f} s wall (median of {len(b['samples_s'])}: {', '.join(f'{s:.2f}' for s in b['samples_s'])}), {b['cpu_median_s']:.2f} s CPU | <= 2 s |
{frame_rows}
"""
    path = Path(out) / "MESH.md"
    path.write_text(text)
    return path
