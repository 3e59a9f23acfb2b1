"""A hand on the body: a damped spring pulling one particle toward a target point (the demo's mouse).

    force on the grabbed particle i:  f = -k (x_i - target) - c v_i
    in an implicit step (h = dt):     h^2 k/2 |x_i - target|^2 + h c/2 |x_i - x_n,i|^2

``Grab`` holds the particle index, the target and (k, c) in Taichi fields, so moving the mouse or
the stiffness slider never recompiles a kernel. The force passes (``forces.ForceEvaluator``) add
``force``; the implicit solvers add ``energy`` to the step's objective with its gradient and its
Hessian, a multiple of the identity on particle i's diagonal block (``hessian``), so they stay
stable however hard the spring pulls. The target is fixed within a step: the spring is then a
conservative potential plus a damper, and the implicit solvers' energy account (which counts
``energy`` with the springs) holds.

A model carries a grab only where something will pull: ``attach(model)`` before the first step
compiles; a model without one (every ``run``) compiles no grab code.
"""
from __future__ import annotations

import math

import numpy as np
import taichi as ti

NONE = -1  # index of "nothing grabbed"


@ti.data_oriented
class Grab:
    """One grab spring on ``model``; ``hold(i, target)``, ``move(target)``, ``release()``."""

    def __init__(self, model):
        self.model = model
        self.index = ti.field(ti.i32, ())  # grabbed particle, NONE if none
        self.target = ti.Vector.field(3, float, ())  # [m]
        self.k = ti.field(float, ())  # spring stiffness [N/m]
        self.c = ti.field(float, ())  # damper coefficient [N s/m]
        self.index[None] = NONE
        self.set_stiffness(1000.0)

    # -- host side -----------------------------------------------------------------------------
    def set_stiffness(self, k: float, damping: float | None = None):
        """Spring stiffness ``k`` [N/m] and damper coefficient [N s/m]; by default the damper that
        critically damps the grabbed particle alone on the spring, 2 sqrt(k m) (m: the heaviest
        particle), so a pulled body follows the hand without ringing on the spring."""
        if not (k >= 0 and math.isfinite(k)):
            raise ValueError(f"grab stiffness must be a finite number >= 0, not {k}")
        if damping is None:
            damping = 2.0 * math.sqrt(k * float(np.max(self.model.mass_np, initial=0.0)))
        self.k[None] = float(k)
        self.c[None] = float(damping)

    def hold(self, i: int, target):
        """Start pulling particle ``i`` toward ``target`` [m]."""
        if not 0 <= i < self.model.n_particles:
            raise IndexError(f"particle {i} does not exist (0..{self.model.n_particles - 1})")
        self.target[None] = tuple(float(c) for c in target)
        self.index[None] = int(i)

    def move(self, target):
        """New target [m] of the held particle (from the next step on)."""
        self.target[None] = tuple(float(c) for c in target)

    def release(self):
        self.index[None] = NONE

    @property
    def held(self) -> int | None:
        """The grabbed particle's index, or None."""
        i = int(self.index[None])
        return None if i == NONE else i

    # -- kernel side ---------------------------------------------------------------------------
    @ti.func
    def force(self, i, xi, vi):
        """Force [N] of the grab on particle i at position xi [m], velocity vi [m/s]."""
        f = ti.Vector.zero(float, 3)
        if i == self.index[None]:
            f = -self.k[None] * (xi - self.target[None]) - self.c[None] * vi
        return f

    @ti.func
    def energy(self, i, xi):
        """Spring energy [J] k/2 |xi - target|^2 of particle i (0 unless grabbed)."""
        e = ti.cast(0.0, float)
        if i == self.index[None]:
            d = xi - self.target[None]
            e = 0.5 * self.k[None] * d.dot(d)
        return e

    @ti.func
    def step_terms(self, i, xi, x_prev, dt):
        """The grab's part of an implicit step's objective for particle i at xi:
        (h^2 energy + h c/2 |xi - x_prev|^2 [kg m^2], its gradient [kg m], Hessian / I [kg])."""
        value = ti.cast(0.0, float)
        grad = ti.Vector.zero(float, 3)
        hess = ti.cast(0.0, float)
        if i == self.index[None]:
            d = xi - self.target[None]
            u = xi - x_prev
            k, c = self.k[None], self.c[None]
            value = 0.5 * dt * dt * k * d.dot(d) + 0.5 * dt * c * u.dot(u)
            grad = dt * dt * k * d + dt * c * u
            hess = dt * dt * k + dt * c
        return value, grad, hess

    @ti.func
    def active(self):
        return self.index[None] != NONE


def attach(model) -> Grab:
    """Give ``model`` a grab (before any integrator on it compiles a step); returns it."""
    if model.grab is None:
        model.grab = Grab(model)
    return model.grab
