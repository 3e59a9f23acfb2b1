"""A scene turned into a running simulation: model, terrain, integrator and state together.

``Simulation`` owns the objects a scene needs and the clock; ``run`` steps to a duration in
chunks of one output frame, so renderers and state recorders see exact frame times.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import runtime
from ..workarounds import cpu_threads
from .allocation import check_tree_room
from .bodies import BodySpec
from .builder import ModelBuilder
from .contact.bodies import BodyContacts, body_radius
from ..errors import UserError
from .lattice import SPRING_KINDS, rotation_matrix
from .forces import Diagnostics
from .integrators import REGISTRY, make_integrator, names as integrator_names
from .integrators.implicit.health import assess
from .integrators.linear_stability import divergence_hint
from .scene import Scene, scene_from_dict
from .contact.terrain import make_terrain


# Wall time [s] of one launch of a run that keeps no frames (``Simulation._free_run``): long
# enough that the per-launch cost vanishes, short enough for a live progress bar and Ctrl-C.
FREE_RUN_SECONDS = 0.1


def body_spec(body: dict) -> BodySpec:
    """A validated ``[[body]]`` table as a ``BodySpec``."""
    return BodySpec(
        n=body["n"], size=body["size"], shape=body.get("shape", "cube"), mesh=body.get("mesh"), scale=body.get("scale"),
        particle_mass=body["particle_mass"], center=tuple(body["center"]),
        rotation_axis=tuple(body["rotation"]["axis"]), rotation_degrees=body["rotation"]["degrees"],
        velocity=tuple(body["velocity"]), angular_velocity=tuple(body["angular_velocity"]),
        initial_stretch=tuple(body["initial_stretch"]),
        stretch=(body["stretch"]["k"], body["stretch"]["damping"]),
        shear=(body["shear"]["k"], body["shear"]["damping"]),
        bend=(body["bend"]["k"], body["bend"]["damping"]),
    )


def body_table(spec: BodySpec) -> dict:
    """A ``BodySpec`` as the ``[[body]]`` table ``body_spec`` reads back (the inverse of ``body_spec``)."""
    table = {"n": spec.n, "size": spec.size, "shape": spec.shape, "particle_mass": spec.particle_mass,
             "center": list(spec.center), "rotation": {"axis": list(spec.rotation_axis), "degrees": spec.rotation_degrees},
             "velocity": list(spec.velocity), "angular_velocity": list(spec.angular_velocity),
             "initial_stretch": list(spec.initial_stretch),
             **{kind: {"k": getattr(spec, kind)[0], "damping": getattr(spec, kind)[1]}
                for kind in ("stretch", "shear", "bend")}}
    table.update({k: getattr(spec, k) for k in ("mesh", "scale") if getattr(spec, k) is not None})
    if spec.scale is not None:
        del table["size"]  # a mesh scaled by ``scale`` takes its size from the mesh (a scene gives one of the two)
    return table


def step_count(duration: float, dt: float) -> int:
    """Whole steps of ``dt`` [s] a run of ``duration`` [s] takes: the nearest number, at least one."""
    return max(int(round(duration / dt)), 1)


def frame_steps(total_steps: int, fps: float, dt: float) -> list[int]:
    """Step counts at which output frames fall: frame k at the step nearest k / fps.

    Always starts at 0 and ends at ``total_steps`` (the exact final state), strictly increasing.
    Steps per frame are 1 / (fps dt) with the remainder carried, so frame times never drift.
    """
    per_frame = 1.0 / (fps * dt)
    n_frames = int(math.floor(total_steps / per_frame + 1e-9))
    steps = sorted({min(int(round(k * per_frame)), total_steps) for k in range(n_frames + 1)} | {0, total_steps})
    return steps


@dataclass
class RunResult:
    """What ``Simulation.run`` returns; ``frames`` holds (t, x, v) samples if recorded."""

    steps: int
    sim_time: float
    wall_seconds: float
    diverged: bool
    diverged_at: float | None
    diverged_step: int | None
    frames: list = field(default_factory=list)


def build_world(data: dict, springs: bool = True):
    """(model, terrain) of a scene's data: its bodies and the ground they fall on, at rest in
    their start pose (what ``Simulation`` steps; the render process of ``--pipeline overlap``
    builds the same to draw positions it is sent)."""
    builder = ModelBuilder(gravity=data["sim"]["gravity"])
    for body in data["body"]:
        builder.add_cube(body_spec(body))
    model = builder.finalize(springs)  # springs=False: the stencil pass stores none
    t = data["terrain"]
    geometry = {k: v for k, v in t.items() if k != "kind"}
    return model, make_terrain(t["kind"], model.n_particles, geometry, **data["contact"])


def _stores_springs(name: str, options, data: dict) -> bool:
    """Whether integrator ``name`` with ``options`` reads stored springs on this scene (all but the
    stencil pass): the model then stores them in its own tree."""
    from .integrators import integrator_class
    from .integrators.base import running_real_bytes, running_target
    from .memory import counts

    cls = integrator_class(name)
    return cls.stores_springs(cls.configure(options, *running_target(), counts(data, running_real_bytes())))


class Simulation:
    """Everything one scene needs, built once: ``model``, ``terrain``, ``integrator``, ``state``.

    ``dt`` [s] may be changed between steps (kernel argument); stiffness, damping, gravity and
    contact coefficients are fields on ``model`` and ``terrain``.
    """

    def __init__(self, scene: Scene, integrator: str | None = None, dt: float | None = None,
                 options: dict | None = None, check: bool = True):
        data = scene.data
        self.scene = scene
        check_tree_room()
        self.integrator_name = integrator or data["sim"]["integrator"]
        if options is None:
            options = data.get("solver", {})
        self.model, self.terrain = build_world(data, _stores_springs(self.integrator_name, options, data))
        # Body-body contact only where there are bodies to collide: a one-body scene compiles none.
        self.contacts = BodyContacts(self.model, self.terrain) if len(self.model.bodies) > 1 else None
        self.integrator = make_integrator(self.integrator_name, self.model, self.terrain, options, self.contacts)
        self.diagnostics = Diagnostics(self.model, self.terrain)
        self.state = self.model.state()
        self.dt = float(dt if dt is not None else data["sim"]["dt"])
        self.steps = 0
        self.diverged_step: int | None = None
        self.reset()
        if check:  # refuse a body inside the terrain or another body (UserError)
            check_start(self)

    @classmethod
    def from_parts(cls, bodies, terrain="plane", integrator: str = "semi_implicit_euler", dt: float = 1e-3,
                   gravity=None, restitution: float | None = None, friction: float | None = None,
                   solver: dict | None = None, check: bool = True) -> Simulation:
        """A simulation built in Python, without a scene file: the parts become a scene's tables
        and are validated exactly as a TOML scene is (the same ``UserError`` messages, naming the
        key as ``body.0.n`` and so on).

        ``bodies``: a list of ``BodySpec`` or of dicts with the keys of a ``[[body]]`` table
        (docs/scenes.md), missing keys at their defaults. ``terrain``: a kind (``"plane"``,
        ``"none"``, ...) at its default geometry, or a dict with the keys of ``[terrain]``.
        ``integrator``: a registered name; ``dt`` [s]; ``gravity`` [m/s^2], a 3-vector (default
        (0, -9.8, 0)); ``restitution`` [0, 1] and ``friction`` (Coulomb coefficient, >= 0) of
        the contact, at the scene defaults when None; ``solver``: the integrator's options (the
        ``[solver]`` table). ``check`` refuses a body that starts inside the terrain or another body.
        """
        sim = {"integrator": integrator, "dt": dt}
        if gravity is not None:
            sim["gravity"] = list(gravity)
        contact = {k: v for k, v in (("restitution", restitution), ("friction", friction)) if v is not None}
        raw = {"sim": sim, "body": [b if isinstance(b, dict) else body_table(b) for b in bodies],
               "terrain": {"kind": terrain} if isinstance(terrain, str) else terrain,
               "contact": contact, "solver": dict(solver or {})}
        return cls(scene_from_dict(raw, "from_parts", integrator_names=integrator_names()), check=check)

    # -- clock ---------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time [s] (steps x dt; dt changes restart the count from ``time_base``)."""
        return self.time_base + (self.steps - self.steps_base) * self.dt

    @property
    def diverged(self) -> bool:
        return self.diverged_step is not None

    @property
    def diverged_at(self) -> float | None:
        """Simulated time [s] at the end of the step that diverged."""
        return None if self.diverged_step is None else self.time

    def reset(self):
        """Back to the scene's initial state."""
        self.state.set(self.model.x0_np, self.model.v0_np)
        self.terrain.reset(self.state.x)
        self.integrator.reset()
        if self.contacts is not None:
            self.contacts.reset()
        self.steps = 0
        self.steps_base = 0
        self.time_base = 0.0
        self.diverged_step = None

    def set_integrator(self, integrator):
        """Continue from the current state with another integrator (an ``Integrator`` built on
        this simulation's model, terrain and ``contacts``, or a registered name)."""
        if isinstance(integrator, str):
            integrator = make_integrator(integrator, self.model, self.terrain, self.scene.data.get("solver", {}),
                                         self.contacts)
        if integrator.model is not self.model or integrator.contacts is not self.contacts:
            raise ValueError("an integrator for this simulation is built on its model and its contacts "
                             "(make_integrator(name, sim.model, sim.terrain, options, sim.contacts))")
        integrator.reset()
        self.integrator = integrator
        self.integrator_name = integrator.name

    def set_dt(self, dt: float):
        """Change the time step [s] from the next step on."""
        self.time_base = self.time
        self.steps_base = self.steps
        self.dt = float(dt)

    def advance(self, n_steps: int) -> int:
        """Take up to ``n_steps`` steps; returns how many were taken (fewer means diverged)."""
        if self.diverged:
            return 0
        # Taichi's CPU pool pinned one worker to a core for the integrators that want it, when they
        # launch in parallel (cpu_threads.py); a no-op unless the runtime was started to allow it.
        cpu_threads.place(self.integrator.pins_pool_workers and self.integrator.mode == "parallel")
        done = self.integrator.advance(self.state, self.dt, n_steps)
        self.steps += done
        if done < n_steps:
            self.diverged_step = self.steps
        return done

    def measure(self) -> dict:
        """Energies, centre of mass, max speed, min terrain distance of the current state."""
        return self.diagnostics.compute(self.state)

    # -- runs ----------------------------------------------------------------------------
    def run(self, duration: float, fps: float, on_frame=None, record: bool = False, progress=None) -> RunResult:
        """Step for ``duration`` [s], stopping at each output frame (``fps``) and on divergence.

        Without ``on_frame`` and ``record`` nothing needs the frames, and the steps go in long
        launches instead (``_free_run``). ``on_frame(sim)`` is called at t = 0, at every frame and
        at the final state; with ``record`` the (t, x, v) of each of those is kept in
        ``RunResult.frames``. ``progress``, if given, is called as ``progress(steps_done,
        total_steps, sim)``.
        """
        total = step_count(duration, self.dt)
        if on_frame is None and not record:
            schedule = None  # nobody looks at the frames: step in long launches (_free_run)
        else:
            schedule = frame_steps(total, fps, self.dt)
        frames = []
        start = time.perf_counter()
        base = self.steps

        def visit():
            if record:
                x, v = self.state.numpy()
                frames.append((self.time, x, v))
            if on_frame is not None:
                on_frame(self)

        visit()
        if schedule is None:
            self._free_run(total, progress)
        for target in schedule[1:] if schedule else ():
            want = base + target - self.steps
            self.advance(want)
            if self.diverged:
                if on_frame is not None:
                    on_frame(self)
                break
            visit()
            if progress is not None:
                progress(self.steps - base, total, self)
        wall = time.perf_counter() - start
        return RunResult(self.steps - base, self.time, wall, self.diverged, self.diverged_at, self.diverged_step, frames)

    def _free_run(self, total: int, progress=None):
        """``total`` steps with no frame stops, in launches of FREE_RUN_SECONDS of wall time or more.

        Stopping at every output frame costs a launch and a few checks per frame (about 0.3 ms at
        n = 10, where a 30 fps frame of 1 ms steps is 2-2.5 ms of work; docs/benchmarks/README.md,
        "Speed"). Chunks start at 16 steps and double while a launch takes less than
        FREE_RUN_SECONDS, so the progress bar still moves.
        """
        base, chunk = self.steps, 16
        while self.steps - base < total and not self.diverged:
            t0 = time.perf_counter()
            self.advance(min(chunk, total - (self.steps - base)))
            if time.perf_counter() - t0 < FREE_RUN_SECONDS:
                chunk *= 2
            if progress is not None:
                progress(self.steps - base, total, self)

    def suggest_dt(self) -> float:
        """A step [s] to try after a divergence (see ``divergence_hint``)."""
        return self.divergence_hint()[0]

    def divergence_hint(self) -> tuple[float, str]:
        """(step [s], one sentence) after a divergence: below the method's linear stability limit
        for this scene, and the methods that take the current step (``linear_stability``)."""
        return divergence_hint(self.model, self.integrator_name, self.dt)

    def summary(self, result: RunResult) -> dict:
        """The run summary (what ``--summary`` writes)."""
        m = self.model
        final = self.measure()
        stats = {**self.integrator.stats(), **(self.contacts.stats() if self.contacts else {})}
        warnings, meaningless = assess(stats)
        if int(self.terrain.impact_at_crossing[None]) and not self.integrator.answers_at_crossing:
            those = " and ".join(name for name, cls in REGISTRY.items() if cls.answers_at_crossing)
            warnings = warnings + [f"contact.impact_at_crossing is set, but {self.integrator_name} answers an impact "
                                   f"where its step ends ({those} answer it at the crossing)"]
        return {
            "scene": self.scene.name,
            "integrator": self.integrator_name,
            "dt": self.dt,
            "steps": result.steps,
            "sim_time": result.sim_time,
            "particles": m.n_particles,
            "springs": m.spring_counts(),
            "bodies": len(m.bodies),
            **({"mesh_bodies": {str(b): d for b, d in mesh_bodies(m).items()}} if any(b.mesh is not None for b in m.bodies) else {}),
            "terrain": self.terrain.kind,
            **{k: v for k, v in (runtime.current() or {}).items() if k in ("arch", "precision", "fast_math")},
            "diverged": result.diverged,
            "diverged_at": result.diverged_at,
            "wall_seconds": result.wall_seconds,
            "steps_per_second": result.steps / result.wall_seconds if result.wall_seconds > 0 else None,
            "integrator_stats": stats,
            "solver_warnings": warnings,
            "meaningless": meaningless,
            "final": {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in final.items()},
        }


def check_start(sim: Simulation):
    """Refuse (``UserError``) a start state with a body inside the terrain or inside another body."""
    d = sim.terrain.signed_distances(sim.state.x)
    for b, body in enumerate(sim.model.bodies):
        depth = -float(d[body.particles].min())
        if depth > 0:
            raise UserError(f"body.{b} starts {depth:.3g} m inside the terrain ({sim.terrain.kind}); "
                            f"move it out (body.{b}.center)")
    check_terrain_crossing(sim, d)
    x0 = sim.model.x0_np
    bodies = sim.model.bodies
    for b, body in enumerate(bodies):
        for a in range(b):
            ra, rb = body_radius(bodies[a].spec), body_radius(body.spec)
            if bodies[a].mesh is not None or body.mesh is not None:
                depth = particle_overlap(x0[bodies[a].particles], x0[body.particles], ra + rb)
            else:
                depth = overlap_depth(bodies[a].spec, x0[body.particles], ra, rb)
            if depth > 0:
                raise UserError(f"body.{b} starts {depth:.3g} m inside body.{a} (particles of different bodies "
                                f"must start at least their contact distance apart); move them apart (body.{b}.center)")


def check_terrain_crossing(sim: Simulation, d: np.ndarray):
    """Refuse (``UserError``) a body whose springs the terrain's surface passes through at the start
    (``d``: the particles' signed distances [m]): it straddles the surface with no particle inside."""
    # A spring the surface crosses has both ends within its length of the surface; a lattice spring
    # is at most a body diagonal of two cells, 2 sqrt(3) spacings (= 4 sqrt(3) contact radii).
    bodies = sim.model.bodies
    reach, owner = np.zeros(len(d)), np.zeros(len(d), dtype=np.int64)
    for b, body in enumerate(bodies):
        reach[body.particles] = 4.0 * math.sqrt(3.0) * body_radius(body.spec) * max(1.0, *body.spec.initial_stretch)
        owner[body.particles] = b
    near = d < reach
    if near.sum() < 2:
        return
    ends = sim.model.pairs_among(near)
    x = sim.state.x.to_numpy().astype(np.float64)
    cut = ends[sim.terrain.crossed(x[ends[:, 0]], x[ends[:, 1]]), 0]
    for b, count in enumerate(np.bincount(owner[cut], minlength=len(bodies))):
        if count:
            raise UserError(f"body.{b} starts cut by the terrain's surface ({sim.terrain.kind}: it passes "
                            f"through {count} of the body's springs); move it clear (body.{b}.center)")


def overlap_depth(spec: BodySpec, points: np.ndarray, radius: float, point_radius: float) -> float:
    """How deep [m] the deepest of ``points`` lies inside the box of body ``spec`` grown by the
    contact distance (radius + point_radius); 0 if none is inside."""
    rot = rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
    q = (points - np.asarray(spec.center)) @ rot  # in the body's axes
    half = 0.5 * spec.size * np.asarray(spec.initial_stretch) + radius + point_radius
    depth = (half - np.abs(q)).min(axis=1)
    return float(max(depth.max(), 0.0))


def particle_overlap(a: np.ndarray, b: np.ndarray, distance: float) -> float:
    """How far [m] the closest pair of points of ``a`` and ``b`` [n, 3] is inside ``distance``; 0 if none is."""
    from scipy.spatial import cKDTree

    closest, _ = cKDTree(a).query(b, k=1, distance_upper_bound=distance)
    return float(max(distance - closest.min(), 0.0))


def body_lines(model) -> list[str]:
    """One line per mesh body: what was read and what it made (the summary's ``mesh_bodies`` too)."""
    return [f"body.{b}: {d['mesh']}: {d['triangles']} triangles, n = {d['n']} (spacing {d['spacing']:.3g} m) -> "
            f"{d['particles']} particles, {sum(d['springs'].values())} springs"
            + "".join(f"; {note}" for note in d["notes"]) for b, d in mesh_bodies(model).items()]


def mesh_bodies(model) -> dict:
    """{body index: facts} of the model's mesh bodies: file, triangles, n, spacing [m], particles,
    springs by kind, particles dropped, volume of the mesh and of the filled lattice [m^3], notes."""
    out = {}
    for b, info in enumerate(model.bodies):
        m = info.mesh
        if m is None:
            continue
        out[b] = {"mesh": str(m.path), "triangles": len(m.triangles), "n": info.spec.n, "spacing": m.h,
                  "particles": m.n_particles, "springs": dict(zip(SPRING_KINDS, m.spring_counts())),
                  "dropped": m.dropped, "mesh_volume": m.mesh_volume, "lattice_volume": m.n_particles * m.h ** 3,
                  "notes": list(m.notes)}
    return out


def states_arrays(frames: list, real) -> dict:
    """(t, x, v) samples -> arrays for ``np.savez``: t [frames], x and v [frames, particles, 3]."""
    if not frames:
        return {"t": np.zeros(0), "x": np.zeros((0, 0, 3), real), "v": np.zeros((0, 0, 3), real)}
    return {
        "t": np.array([f[0] for f in frames], dtype=np.float64),
        "x": np.stack([f[1] for f in frames]).astype(real, copy=False),
        "v": np.stack([f[2] for f in frames]).astype(real, copy=False),
    }
