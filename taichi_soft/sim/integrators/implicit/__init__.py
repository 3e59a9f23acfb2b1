"""Implicit integrators: backward Euler by Newton + PCG (``implicit_euler``) and fast mass-spring
local/global (``fast_mass_spring``), both minimising the step's objective (docs/implicit.md).

* ``options``: the options of both, typed and documented in one place;
* ``objective``: inertia, springs, dampers and friction: values and gradient;
* ``contact``: feasible start, active set with hysteresis, frozen friction, restitution;
* ``pairs``: contact between bodies (candidate pairs, penalty, friction, restitution);
* ``driver``: the one driver both solvers share (serial in-kernel and parallel Python loops
  sequence the same decision functions), the step's energy account;
* ``laplacian``: the constant matrix M + L and its skyline Cholesky factor;
* ``newton``: ``implicit_euler`` (Hessian, PCG operator);
* ``local_global``: ``fast_mass_spring`` (prefactored global matrix, L-BFGS).
"""
from .driver import ImplicitIntegrator
from .laplacian import CHOLESKY_AUTO_MAX
from .local_global import FastMassSpring
from .newton import ImplicitEuler

__all__ = ["ImplicitIntegrator", "ImplicitEuler", "FastMassSpring", "CHOLESKY_AUTO_MAX"]
