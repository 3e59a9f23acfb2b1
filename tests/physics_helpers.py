"""Small builders shared by the physics tests (no Taichi initialisation here)."""
import numpy as np
import taichi as ti

from taichi_soft.sim.bodies import BodySpec
from taichi_soft.sim.builder import ModelBuilder
from taichi_soft.sim.forces import ForceEvaluator
from taichi_soft.sim.integrators import make_integrator
from taichi_soft.sim.contact.terrain import CONTACT_DEFAULTS, make_terrain


def build(n=4, size=1.5, gravity=(0.0, 0.0, 0.0), terrain="none", geometry=None, contact=None, **body):
    """(model, terrain) for one cube; body keyword arguments go to ``BodySpec``."""
    b = ModelBuilder(gravity=gravity)
    b.add_cube(BodySpec(n=n, size=size, **body))
    model = b.finalize()
    c = dict(CONTACT_DEFAULTS)
    c.update(contact or {})
    return model, make_terrain(terrain, model.n_particles, geometry or {}, **c)


def moving_cube(n=4, damping=60.0, k=2000.0):
    """(model, terrain, x0): an n^3 cube, edge 1.5 m, 1 kg particles, springs k [N/m] with dampers
    [N s/m], spinning and translating under gravity with no terrain, x0 stretched by up to 30 %:
    smooth motion for the implicit solvers' convergence and scheme tests."""
    model, terrain = build(n=n, size=1.5, gravity=(0.0, -9.8, 0.0), stretch=(k, damping), shear=(k, damping),
                           bend=(k, damping), angular_velocity=(0.0, 3.0, 1.0), velocity=(1.0, 0.0, 0.0))
    return model, terrain, stretched(model, (1.3, 0.8, 1.1))


def stretched(model, factor=(1.1, 0.95, 1.0)):
    """Initial positions [m] stretched about the centre of mass by per-axis ``factor``."""
    x0 = model.x0_np
    com = x0.mean(axis=0)
    return com + (x0 - com) * np.asarray(factor)


def simulate(model, terrain, integrator, dt, steps, x0=None, v0=None, options=None):
    """Run ``steps`` steps; returns (x, v, steps_done) as numpy arrays."""
    return run_integrator(make_integrator(integrator, model, terrain, options), model, terrain, dt, steps, x0, v0)


def run_integrator(integ, model, terrain, dt, steps, x0=None, v0=None):
    """``simulate`` with an integrator already built (reset first, so one compile serves many runs)."""
    integ.reset()
    state = model.state()
    state.set(model.x0_np if x0 is None else x0, model.v0_np if v0 is None else v0)
    terrain.reset(state.x)
    done = integ.advance(state, dt, steps)
    x, v = state.numpy()
    return x, v, done


def spring_energy(model, x) -> float:
    """Sum of 1/2 k (|x_a - x_b| - r)^2 [J] over all springs, in numpy."""
    a, b = model.pairs_np[:, 0], model.pairs_np[:, 1]
    k = model.group_k.to_numpy()[model.group_np]
    length = np.linalg.norm(x[a] - x[b], axis=1)
    return float(0.5 * np.sum(k * (length - model.rest_np) ** 2))


def total_energy(model, x, v) -> float:
    """Kinetic + gravity + spring energy [J]."""
    g = model.gravity[None].to_numpy()
    return float(0.5 * np.sum(model.mass_np[:, None] * v * v) - np.sum(model.mass_np * (x @ g)) + spring_energy(model, x))


@ti.kernel
def _eval(fe: ti.template(), x: ti.template(), v: ti.template(), a: ti.template()):
    fe.compute(x, v, 1e-3, a)


def accelerations(model, terrain, x, v, strategy="per_spring"):
    """Acceleration [m/s^2] of every particle at (x, v), through the engine's force evaluator."""
    fe = ForceEvaluator(model, terrain, strategy)
    state = model.state()
    state.set(x, v)
    a = ti.Vector.field(3, float, model.n_particles)
    _eval(fe, state.x, state.v, a)
    return a.to_numpy()


def numeric_gradient(fn, x, h=1e-6) -> np.ndarray:
    """Central finite differences of the scalar ``fn`` with respect to every entry of ``x``."""
    grad = np.zeros_like(x)
    for idx in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[idx] += h
        xm[idx] -= h
        grad[idx] = (fn(xp) - fn(xm)) / (2 * h)
    return grad


def default_cube_sim(cache: dict, terrain: str, integrator: str, dt: float, stiffness: float = 1.0):
    """The scene ``terrain``'s default cube with ``integrator`` (built once into ``cache``: each test
    module keeps its own, as each has its own Taichi runtime), reset, at ``dt`` [s], its springs'
    stiffness ``stiffness`` x 2000 N/m."""
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    key = (terrain, integrator)
    if key not in cache:
        cache[key] = Simulation(load_scene(terrain, integrator_names=names()), integrator, dt)
    sim = cache[key]
    for kind in ("stretch", "shear", "bend"):
        sim.model.set_spring_params(0, kind, k=2000.0 * stiffness)
    sim.set_dt(dt)
    sim.reset()
    return sim
