"""The implicit step's control flow, written once, and the two ways it runs.

A step (docs/implicit.md) is a sequence of phases: begin; the reference g(x_n) and the feasible
start (line searches without a direction); iterations of gradient and decision, search direction,
line search (trial and decision), accept; end (velocities, the restitution spread, finish). Every
decision is a ti.func that writes the step's scalars (``sc``: scalars.py). ``step`` below is
the sequence as plain Python control flow over those scalars, and it runs from this one source:

* inside a kernel (the serial driver: one launch runs many steps on one thread):
  ``STEP.func = ti.func(step)`` with ``InKernel`` phases, each an inlined ti.func call;
* from Python scope (the parallel driver): ``STEP.py = step`` with ``Launches`` phases, each a
  kernel launch whose loops over particles and springs run in parallel; each scalar read is a
  device sync.

``InKernel`` and ``Launches`` implement the same phase list, one line each. A solver's own
sequences (its search direction: ``DIRECTION``) are walks too and call the same executors (a
solver with phases of its own extends both classes), so the two drivers take the same decisions
by construction, not by keeping two copies alike.
"""

import taichi as ti


class Walk:
    """A sequence of phases ``fn(integ, ph, x)`` (or more arguments): ``py`` runs it from Python
    scope, ``func`` is the same source as a ti.func for the inside of a kernel."""

    def __init__(self, fn):
        self.py = fn
        self.func = ti.func(fn)
        self.__doc__ = fn.__doc__


def _step(integ, ph, x, v, dt, step):
    """One step of h = ``dt`` [s] from (x, v), step index ``step`` (the divergence record)."""
    ph.begin(x, v, dt)
    he = integ.scheme.h_eff[None]  # the scheme's h: dt, or 2 dt / 3 for BDF2
    # Phases 0 (reference at x_n) and 1 (feasible start) are line searches without a direction,
    # so one loop runs all three phases and every phase has a single call site (the serial
    # kernel inlines each call site; fewer sites compile faster).
    for _k in range(integ.max_iters[None] + integ.max_updates[None] + 3):
        searching = integ.sc.phase[None] < 2
        if not searching:
            ph.gradient(x, he)
            if integ.sc.done[None]:
                break
            searching = integ.sc.update[None] == 0  # no friction refreeze pending: take a step
            if searching:
                ph.walk(integ.DIRECTION, x)
                ph.after_direction()
                if ti.static(integ._has_pairs()):
                    ph.pairs_check()  # rebuild the pair list if the line search could leave its tube
                    if integ.pairs.again[None]:
                        ph.pairs_regather()
        if searching:
            for _h in range(integ.sc.ls_limit[None] + 1):
                ph.trial(x, he)
                if integ.sc.ls_done[None]:
                    break
            ph.accept(x)
            if integ.sc.done[None]:
                break
    ph.end_velocities(x, he)
    if ti.static(integ.terrain.has_contact):
        if integ.sc.n_bounce[None] > 0:  # restitution carried by the springs (restitution.py)
            ph.bounce_rhs()
            ph.cg(integ.spread.rhs, integ.spread.response)
    ph.end_finish(x, v, step)


STEP = Walk(_step)


def _cg_direction(integ, ph, x):
    """dx from rhs by the solver's PCG (Newton's direction)."""
    ph.cg(integ.objective.rhs, integ.objective.dx)


CG_DIRECTION = Walk(_cg_direction)


@ti.data_oriented
class InKernel:
    """The phases as ti.funcs, for ``STEP.func`` inside the serial driver's kernel."""

    def __init__(self, integ):
        self.i = integ

    @ti.func
    def walk(self, w: ti.template(), x: ti.template()):
        w.func(self.i, self, x)

    @ti.func
    def begin(self, x: ti.template(), v: ti.template(), dt):
        self.i._begin_step(x, v, dt)

    @ti.func
    def gradient(self, x: ti.template(), dt):
        self.i.objective.gradient(x, dt)
        self.i._after_gradient(dt)

    @ti.func
    def after_direction(self):
        self.i._after_direction()

    @ti.func
    def pairs_check(self):
        self.i.pairs.check()

    @ti.func
    def pairs_regather(self):
        self.i.pairs.regather()

    @ti.func
    def trial(self, x: ti.template(), dt):
        self.i.objective.trial(x, dt)
        self.i._line_search_decide()

    @ti.func
    def accept(self, x: ti.template()):
        self.i._accept(x)

    @ti.func
    def cg(self, b: ti.template(), out: ti.template()):
        """out = A^-1 b by the solver's PCG (to its current ``rel_tol``), counted in ``sc.cg``."""
        self.i.pcg.solve(self.i, b, out, self.i.cg_iters[None])
        self.i.sc.cg[None] += self.i.pcg.iters[None]

    @ti.func
    def end_velocities(self, x: ti.template(), dt):
        self.i.end.velocities(x, dt)

    @ti.func
    def bounce_rhs(self):
        self.i._bounce_rhs()

    @ti.func
    def end_finish(self, x: ti.template(), v: ti.template(), step):
        self.i.end.finish(x, v, step)


@ti.data_oriented
class Launches:
    """The phases as kernel launches, for ``STEP.py`` from Python scope (the parallel driver)."""

    def __init__(self, integ):
        self.i = integ

    def walk(self, w, x):
        w.py(self.i, self, x)

    @ti.kernel
    def begin(self, x: ti.template(), v: ti.template(), dt: float):
        self.i._begin_step(x, v, dt)

    @ti.kernel
    def gradient(self, x: ti.template(), dt: float):
        self.i.objective.gradient(x, dt)
        self.i._after_gradient(dt)

    @ti.kernel
    def after_direction(self):
        self.i._after_direction()

    @ti.kernel
    def pairs_check(self):
        self.i.pairs.check()

    @ti.kernel
    def pairs_regather(self):
        self.i.pairs.regather()

    @ti.kernel
    def trial(self, x: ti.template(), dt: float):
        self.i.objective.trial(x, dt)
        self.i._line_search_decide()

    @ti.kernel
    def accept(self, x: ti.template()):
        self.i._accept(x)

    def cg(self, b, out):
        """The same solve, one launch per CG iteration."""
        self._add_cg(self.i.pcg.solve_parallel(self.i, b, out, int(self.i.cg_iters[None])))

    @ti.kernel
    def _add_cg(self, iters: ti.i32):
        self.i.sc.cg[None] += iters

    @ti.kernel
    def end_velocities(self, x: ti.template(), dt: float):
        self.i.end.velocities(x, dt)

    @ti.kernel
    def bounce_rhs(self):
        self.i._bounce_rhs()

    @ti.kernel
    def end_finish(self, x: ti.template(), v: ti.template(), step: ti.i32):
        self.i.end.finish(x, v, step)
