"""Implicit integrators: backward Euler by Newton + PCG (``implicit_euler``) and fast mass-spring
local/global (``fast_mass_spring``), both minimising the step's objective (docs/implicit.md).

* ``options``: the options of both, typed and documented in one place;
* ``driver``: the one driver both solvers share and the parts it is built from (the phases are
  written once in ``walk``: the serial in-kernel and the parallel Python driver sequence the same
  decision functions, on the step's named scalars, ``scalars``); the step's end and energy
  account (``step_end``, ``accounts``);
* ``objective``: inertia, springs, dampers and friction: values and gradient;
* parts given what they read at construction: ``contact`` (the terrain's feasible start, active
  set with hysteresis, frozen friction and restitution), ``restitution`` (the bounce spread
  through the body), ``scheme`` (backward Euler or BDF2 per step) and ``fast_mass_spring_laplacian`` (the constant
  matrix M + L and its skyline Cholesky factor); ``pairs`` (contact between bodies: candidate
  pairs, penalty, friction, restitution) is built with its owner and reads the owner's step fields;
* ``implicit_euler``: that solver, Newton + PCG (its Hessian blocks as a part, the PCG operator);
* ``fast_mass_spring``: that solver, local/global (the global step with the matrix of
  ``fast_mass_spring_laplacian``, L-BFGS over it in ``fast_mass_spring_lbfgs``).
"""
from .driver import ImplicitIntegrator
from .fast_mass_spring import FastMassSpring
from .fast_mass_spring_laplacian import CHOLESKY_AUTO_MAX
from .implicit_euler import ImplicitEuler

__all__ = ["ImplicitIntegrator", "ImplicitEuler", "FastMassSpring", "CHOLESKY_AUTO_MAX"]
