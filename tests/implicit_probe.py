"""Evaluate an implicit solver's step objective at a given state: the checks of its derivatives
(tests/test_implicit.py). Test code, kept out of the product: it drives the integrator's own
ti.funcs and fields from kernels of its own.

``begin`` starts a step at ``state`` (it does not move the state's free particles); the others
evaluate at ``state.x`` for that step, with no particle held and no friction.
"""
import numpy as np
import taichi as ti


@ti.kernel
def _displace(integ: ti.template(), x: ti.template()):
    for i in range(integ.n):
        integ.objective.u[i] = x[i] - integ.objective.x_prev[i]


@ti.kernel
def _no_contacts(integ: ti.template()):
    for i in range(integ.n):
        integ.contact.release(i)


@ti.kernel
def _trial_at(integ: ti.template(), x: ti.template(), dt: float, alpha: float):
    for i in range(integ.n):
        integ.objective.dx[i] = ti.Vector.zero(float, 3)
    integ.sc.alpha[None] = alpha
    integ.objective.trial(x, dt)


@ti.kernel
def _apply(integ: ti.template(), src: ti.template(), dst: ti.template()):
    integ.apply(src, dst)


def begin(integ, state, dt: float):
    """Start a step of ``dt`` [s] at ``state`` without solving it."""
    integ._sync_masses()
    integ.launches.begin(state.x, state.v, dt)
    _no_contacts(integ)


def objective(integ, state, dt: float) -> float:
    """g(state.x) [kg m^2] for the step begun last."""
    _displace(integ, state.x)
    _trial_at(integ, state.x, dt, 0.0)
    return float(integ.sc.f_trial[None])


def gradient(integ, state, dt: float) -> np.ndarray:
    """grad g(state.x) [kg m], an [n, 3] array."""
    _displace(integ, state.x)
    integ.launches.gradient(state.x, dt)
    return integ.objective.grad.to_numpy()


def hessian_product(integ, state, dt: float, w: np.ndarray) -> np.ndarray:
    """H w [kg m], H the (PSD-clamped) Hessian the solver uses at state.x; w an [n, 3] array."""
    _displace(integ, state.x)
    integ.launches.gradient(state.x, dt)
    src = ti.Vector.field(3, float, integ.n)
    dst = ti.Vector.field(3, float, integ.n)
    src.from_numpy(np.asarray(w, dtype=integ.model.real))
    _apply(integ, src, dst)
    return dst.to_numpy()
