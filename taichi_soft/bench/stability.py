"""Largest stable time step, found by bisection on log(dt).

A run at step dt is *unstable* when, within the horizon, any of these happens:

* the integrator's divergence check fires (a velocity is non-finite or |v|^2 above
  ``integrators.base.DIVERGENCE_SPEED2``, the assignment's check);
* total energy (kinetic + gravity + springs) grows above its initial value by more than
  ``energy_growth`` (default ``ENERGY_GROWTH``) times the scene's initial energy scale (a
  dissipative drop never gains energy);
* a particle sits deeper than ``max_penetration`` [m] (default ``MAX_PENETRATION``) inside the terrain.

``largest_stable_dt(is_stable, lo, hi)`` needs only a predicate, so the same bisection is tested
on a single spring whose limits are known in closed form.
"""
from __future__ import annotations

import math

from ..sim.scene import load_scene
from ..sim.simulation import Simulation

SEED_TABLE = {"explicit_euler": 0.0020, "midpoint": 0.0045, "rk4": 0.0030}  # the seed's plane results [s]

# The stiffness sweep (multiples of the scene's spring stiffness) and the largest step tried [s]:
# from x1, where explicit methods are cheapest, to x1000, where they must crawl.
STIFFNESS_SCALES = (1.0, 10.0, 100.0, 1000.0)
QUICK_STIFFNESS_SCALES = (1.0, 10.0)
DT_MAX = 0.1
# The instability criteria's defaults (module docstring): the horizon [s], the allowed energy
# growth (fraction of the initial energy scale) and the deepest allowed penetration [m].
HORIZON = 2.0
ENERGY_GROWTH = 0.05
MAX_PENETRATION = 0.1


def largest_stable_dt(is_stable, lo: float, hi: float, rel_tol: float = 0.02, max_iter: int = 30) -> dict:
    """Bisection on log(dt) between ``lo`` (should be stable) and ``hi`` (should be unstable).

    Returns {"dt": largest stable dt found, "bracket": (stable, unstable), "bounded": bool}. If ``hi``
    is stable, returns it with bounded False ("at least hi"); if ``lo`` is unstable, dt is None.
    """
    if is_stable(hi):
        return {"dt": hi, "bracket": (hi, None), "bounded": False}
    if not is_stable(lo):
        return {"dt": None, "bracket": (None, lo), "bounded": True}
    for _ in range(max_iter):
        if hi / lo <= 1 + rel_tol:
            break
        mid = math.sqrt(lo * hi)
        if is_stable(mid):
            lo = mid
        else:
            hi = mid
    return {"dt": lo, "bracket": (lo, hi), "bounded": True}


class SceneProbe:
    """``probe(dt) -> stable?`` for one scene and integrator; reuses one compiled ``Simulation``.

    ``stiffness_scale`` multiplies every spring stiffness (a run-time field: no recompile).
    """

    def __init__(self, scene_name: str, integrator: str, overrides=(), horizon: float = HORIZON,
                 energy_growth: float = ENERGY_GROWTH, max_penetration: float = MAX_PENETRATION):
        self.sim = Simulation(load_scene(scene_name, list(overrides)), integrator=integrator)
        self.horizon = horizon
        self.energy_growth = energy_growth
        self.max_penetration = max_penetration
        self.base_k = self.sim.model.group_k.to_numpy().copy()
        self.last_reason = ""

    def set_stiffness_scale(self, scale: float):
        self.sim.model.set_group_stiffness(self.base_k[: self.sim.model.n_groups] * scale)

    def __call__(self, dt: float) -> bool:
        sim = self.sim
        sim.reset()
        sim.set_dt(dt)
        e0 = sim.measure()
        scale = max(abs(e0["total_energy"]), abs(e0["gravity_energy"]), 1.0)
        limit = e0["total_energy"] + self.energy_growth * scale
        total = int(math.ceil(self.horizon / dt))
        chunk = max(1, int(round(0.05 / dt)))  # check energy and depth every 50 ms of simulated time
        done = 0
        while done < total:
            n = min(chunk, total - done)
            sim.advance(n)
            done += n
            if sim.diverged:
                self.last_reason = f"diverged at t = {sim.time:.3f} s"
                return False
            m = sim.measure()
            if not m["total_energy"] <= limit:
                self.last_reason = f"energy grew at t = {sim.time:.3f} s"
                return False
            depth = m["min_terrain_distance"]
            if depth is not None and depth < -self.max_penetration:
                self.last_reason = f"penetrated {-depth:.3f} m at t = {sim.time:.3f} s"
                return False
        self.last_reason = ""
        return True
