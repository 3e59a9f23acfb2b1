"""The implicit step's control flow and its phases, each written once, and the two ways they run.

A step (docs/implicit.md) is a sequence of phases: begin; the reference g(x_n) and the feasible
start (line searches without a direction); iterations of gradient and decision, search direction,
line search (trial and decision), accept; end (velocities, the restitution spread, finish). Every
decision is a ti.func that writes the step's scalars (``sc``: scalars.py).

* ``PHASES`` declares each phase once: its name, the integrator's ti.func that does its work and
  the kinds of that function's arguments. A solver with phases of its own (fast_mass_spring's
  factor solve and L-BFGS) adds them to its class's ``PHASES``.
* ``step`` below is the sequence as plain Python control flow over the scalars, calling phases by
  name on an executor ``ph``. It runs from this one source:

  - inside a kernel (the serial driver: one launch runs many steps on one thread):
    ``STEP.func = ti.func(step)`` with ``InKernel``, whose phase ``name`` is the declared ti.func
    itself, inlined at the call site;
  - from Python scope (the parallel driver): ``STEP.py = step`` with ``Launches``, whose phase
    ``name`` is one kernel launch of the declared ti.func (one compiled kernel per phase), its
    loops over particles and springs parallel; each scalar read is a device sync.

Both executors are generated from the declaration, so the two drivers take the same decisions by
construction, not by keeping copies alike. Only the entries that are no single ti.func are
written per executor: ``walk`` (a sequence within the step: a solver's ``DIRECTION``), ``step``
(one whole step, for a scheme of several solves a step: ``SDIRK2_STEP``) and ``cg`` (the linear
solve: one loop inside the kernel, one launch per CG iteration from Python).
"""

import taichi as ti

# The kinds of a phase's arguments: a field (a template argument), a real (a time [s]), a count
# (an index: the step, an L-BFGS pair).
FIELD, REAL, COUNT = "field", "real", "count"

# The shared phases: name -> (the ti.func that does the work, as an attribute path from the
# integrator; the kinds of its arguments, in order).
PHASES = {
    "begin": ("_begin_step", (FIELD, FIELD, REAL)),  # x, v, dt
    "gradient": ("_gradient", (FIELD, REAL)),  # x, h
    "after_direction": ("_after_direction", ()),
    "pairs_check": ("pairs.check", ()),
    "pairs_regather": ("pairs.regather", ()),
    "trial": ("_trial", (FIELD, REAL)),  # x, h
    "accept": ("_accept", (FIELD,)),  # x
    "end_velocities": ("end.velocities", (FIELD, REAL)),  # x, h
    "bounce_rhs": ("_bounce_rhs", ()),
    "end_finish": ("end.finish", (FIELD, FIELD, COUNT)),  # x, v, step
    "restore_stage": ("_restore_stage", (FIELD, FIELD)),  # x, v: SDIRK2's X1, V1 again
}


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


def _sdirk2_step(integ, ph, x, v, dt, step):
    """SDIRK2's step of ``dt`` [s] (scheme.py): two solves, and a second stage that gained energy
    taken again from (X1, V1) as a backward-Euler solve over the same time (counted:
    ``sdirk2_fallback_steps``)."""
    for stage in range(3):
        if stage < 2 or integ.scheme.redo[None]:
            if stage == 2:
                ph.restore_stage(x, v)
            integ.scheme.stage[None] = stage + 1
            ph.step(x, v, integ._stage_dt(stage, dt), step)


SDIRK2_STEP = Walk(_sdirk2_step)


def _cg_direction(integ, ph, x):
    """dx from rhs by the solver's PCG (Newton's direction)."""
    ph.cg(integ.objective.rhs, integ.objective.dx)


CG_DIRECTION = Walk(_cg_direction)


def _work(integ, name: str):
    """The ti.func phase ``name`` of ``integ.PHASES`` names, bound to its owner (the integrator or
    one of its parts, looked up when called: a part such as ``pairs`` may be set after
    construction)."""
    owner = integ
    *parts, attr = integ.PHASES[name][0].split(".")
    for part in parts:
        owner = getattr(owner, part)
    return getattr(owner, attr)


def _is_phase(executor, name: str) -> bool:
    integ = executor.__dict__.get("i")
    return integ is not None and not name.startswith("_") and name in integ.PHASES


@ti.data_oriented
class InKernel:
    """The phases as ti.funcs, for ``STEP.func`` inside the serial driver's kernel: ``ph.name(...)``
    is the declared ti.func itself."""

    def __init__(self, integ):
        self.i = integ

    def __getattr__(self, name):
        if not _is_phase(self, name):
            raise AttributeError(name)
        return _work(self.i, name)

    @ti.func
    def walk(self, w: ti.template(), x: ti.template()):
        w.func(self.i, self, x)

    @ti.func
    def step(self, x: ti.template(), v: ti.template(), dt, step):
        STEP.func(self.i, self, x, v, dt, step)

    @ti.func
    def cg(self, b: ti.template(), out: ti.template()):
        """out = A^-1 b by the solver's PCG (to its current ``rel_tol``), counted in ``sc.cg``."""
        self.i.pcg.solve(self.i, b, out, self.i.cg_iters[None])
        self.i.sc.cg[None] += self.i.pcg.iters[None]


@ti.data_oriented
class Launches:
    """The phases as kernel launches, for ``STEP.py`` from Python scope (the parallel driver):
    ``ph.name(...)`` launches ``_phase``, compiled once per phase (and per field it is given)."""

    def __init__(self, integ):
        self.i = integ

    def __getattr__(self, name):
        if not _is_phase(self, name):
            raise AttributeError(name)
        kinds = self.i.PHASES[name][1]

        def launch(*args):
            fields = tuple(a for a, kind in zip(args, kinds) if kind == FIELD)
            real = next((a for a, kind in zip(args, kinds) if kind == REAL), 0.0)
            count = next((a for a, kind in zip(args, kinds) if kind == COUNT), 0)
            self._phase(name, fields, real, count)

        self.__dict__[name] = launch  # built once per phase
        return launch

    @ti.kernel
    def _phase(self, name: ti.template(), fields: ti.template(), real: float, count: ti.i32):
        work = ti.static(_work(self.i, name))
        args = ti.static(_arguments(self.i.PHASES[name][1], fields, real, count))
        work(*args)

    def walk(self, w, x):
        w.py(self.i, self, x)

    def step(self, x, v, dt, step):
        STEP.py(self.i, self, x, v, dt, step)

    def cg(self, b, out):
        """The same solve, one launch per CG iteration."""
        self._add_cg(self.i.pcg.solve_parallel(self.i, b, out, int(self.i.cg_iters[None])))

    @ti.kernel
    def _add_cg(self, iters: ti.i32):
        self.i.sc.cg[None] += iters


def _arguments(kinds, fields, real, count) -> tuple:
    """A phase's arguments in its declared order, from a launch's fields, real and count."""
    out, rest = [], iter(fields)
    for kind in kinds:
        out.append(next(rest) if kind == FIELD else real if kind == REAL else count)
    return tuple(out)
