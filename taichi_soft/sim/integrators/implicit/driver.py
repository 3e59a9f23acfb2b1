"""One driver for both implicit solvers: start, iterate, end the step; serial and parallel alike.

A step (docs/implicit.md):

1. ``_begin_step``: save (x_n, v_n), freeze damper directions, predict y, choose the start
   direction (the terrain contact part, contact.py) and measure the energy the step begins with.
2. Reference and feasible start: g(x_n) (a trial at alpha = 0), then a line search from x_n
   along the start direction, beginning at the largest
   feasible fraction ``sc.t_max``, accepting the first fraction with g <= g(x_n) (at most
   ``START_HALVINGS`` halvings, else the step starts at x_n).
3. Iterations: gradient (and the linear operator's data) -> decision (converged? refreeze friction?) -> direction (the subclass:
   Newton + PCG, or the prefactored local/global matrix) -> Armijo backtracking -> accept.
4. The end (step_end.py): v = (x - x_n)/h, restitution within the energy the step lost, ``_finish``
   (``Terrain.respond``, divergence check), and, as a counted last resort, the energy clamp.

Every decision (convergence tests, Armijo, the forcing term, recording) is a ti.func writing
the step's scalars (``sc``: scalars.py). The sequence of phases is written once (walk.py): the
serial driver runs it inside the one-launch kernel of many steps, the parallel driver from Python
scope, one launch per phase. The parts it composes, each given what it reads at construction: the
objective g (objective.py), the terrain contact (contact.py), the body-body pairs (pairs.py), the
scheme (scheme.py), the restitution spread (restitution.py), the PCG (linalg.py), the step's end
(step_end.py, phase 4) and the step's counters (accounts.py).
"""

import numpy as np
import taichi as ti

from ...footprint import ADJACENCY, FieldCounts
from ...linalg import PCG
from ...model import CHANGED_MASSES
from ...scalar_fields import assign
from ..base import Integrator
from .accounts import StepAccounts, spring_passes_per_step
from .contact import TerrainContact
from .objective import Objective
from .options import ImplicitConfig
from .pairs import PairContacts
from .restitution import BOUNCE_CG_TOL, BounceSpread
from .scalars import START_HALVINGS, counters, step_scalars
from .scheme import SDIRK_GAMMA, StepScheme
from .step_end import StepEnd
from .walk import CG_DIRECTION, SDIRK2_STEP, STEP, InKernel, Launches
from .walk import PHASES as SHARED_PHASES


@ti.data_oriented
class ImplicitIntegrator(Integrator):
    """Shared machinery of ``implicit_euler`` and ``fast_mass_spring``.

    A solver is its own linear operator: subclasses implement ``operator.LinearOperator``
    (``store_spring_hessian(s, block)`` and ``store_preconditioner(i)``, the ti.funcs the gradient
    pass calls, storing whatever ``apply`` and ``precondition`` need; ``prepare_preconditioner``;
    ``grab_factored(i)``, False here), ``DIRECTION``
    (a ``walk.Walk``: dx from rhs at the iterate x; by default the PCG solve) and ``Config`` (an
    ``options.ImplicitConfig``: its ``residual_tol`` and ``max_iterations`` stop the iterations). A
    solver whose direction has phases of its own adds them to ``PHASES`` (walk.py: name -> its
    ti.func and argument kinds); both executors are generated from that table.

    Fields: a solver declares those of a fixed size in ``BUFFERS`` (the base class allocates them)
    or, for a part it builds (``implicit_euler.SpringHessian``, ``fast_mass_spring_laplacian.LaplacianMatrix``), adds the
    part's table to ``FIELDS``; those whose size depends on its options (a factor, L-BFGS pairs) it
    allocates in ``__init__`` before calling this one's, and declares them in ``buffers``. (Fields
    allocated together, with no kernel launch or field access between them, share one Taichi SNode
    tree; a runtime holds a limited number of trees.)
    """

    implicit = True
    sweep_dt_cap = 2e-2  # A-stable: the sweep reaches frame steps
    pins_pool_workers = False  # its step's many short loops ran slower pinned (cpu_threads.py)
    order = 1
    force_evals = 0
    # No force-pass buffers and no table of its own: the model's adjacency and its parts' tables.
    FIELDS = ADJACENCY + FieldCounts.of(*(part.BUFFERS for part in (
        Objective, PCG, TerrainContact, BounceSpread, StepScheme, StepEnd)))
    Config = ImplicitConfig  # each solver's own extends it (options.py)
    spring_passes_per_step = staticmethod(spring_passes_per_step)  # (accounts.py)
    DIRECTION = CG_DIRECTION  # the search direction's walk (walk.py)
    PHASES = SHARED_PHASES  # the step's phases, each declared once; run inside a kernel or as launches (walk.py)

    def __init__(self, model, terrain, options=None, contacts=None):
        # The parts, allocated before the base class's fields (in the same pending SNode tree
        # unless a subclass's own part wrote a field first: fast_mass_spring's factor does).
        # The step's scalars: f64 whatever the precision: their sums run over every particle
        # (objective, residual, energies), and in f32 a sum over 10^5-10^7 terms lost the line
        # search's decrease and the energy balance to round-off (a large body froze:
        # docs/implicit.md, "Precision").
        self.sc = step_scalars()
        self.pcg = PCG(model.n_particles)  # every linear solve of the step (walk.py's ``cg``)
        self.contact = TerrainContact(model, terrain, self.sc)  # held particles, friction, bounce
        self.spread = BounceSpread(model.n_particles, self.contact, self.sc)  # restitution through the body
        self.scheme = StepScheme(model, terrain, self.sc, self.contact)  # backward Euler or BDF2, per step
        # g(x), its gradient and values; this solver's linear operator takes the gradient pass's blocks
        self.objective = Objective(model, terrain, self.sc, self.scheme, self.contact, operator=self)
        self.accounts = StepAccounts(self.sc, self.scheme)  # what the steps did, for stats()
        self.tol2 = ti.field(float, ())  # tolerance on sc.res2 for this step's h_eff (see _begin_step)
        # phase 4: it ends each particle's step with the base class's ``_finish`` (terrain response,
        # divergence check) and judges the step's residual by ``tol2``
        self.end = StepEnd(model, terrain, self.sc, self.objective, self.contact, self.spread, self.scheme,
                           self.accounts, finish=self._finish, tol2=self.tol2)
        super().__init__(model, terrain, options, contacts)
        o = self.options
        self._counters = counters(self.sc)
        # Limits read by kernels (fields, so changing an option's value needs no recompile).
        self.max_iters = ti.field(ti.i32, ())
        self.ls_iters = ti.field(ti.i32, ())
        self.max_updates = ti.field(ti.i32, ())
        self.cg_iters = ti.field(ti.i32, ())
        self.cg_tol = ti.field(float, ())
        self.ew_forcing = ti.field(ti.i32, ())  # 1: Eisenstat-Walker forcing term
        self.velocity_tol = ti.field(float, ())  # [m/s]
        self.tol_acc = ti.field(float, ())  # the solver's residual tolerance [m/s^2]
        self.roundoff = ti.field(float, ())  # relative objective noise the line search ignores
        # Values only after every field is allocated: the first write closes the pending SNode
        # tree, and the next field would open another (the runtime holds 512: allocation.MAX_TREES).
        self.scheme.use_bdf2(o.scheme == "bdf2")
        self.stages = 2 if o.scheme == "sdirk2" else 1  # SDIRK2: two solves a step
        self.step_walk = SDIRK2_STEP if self.stages > 1 else STEP  # one step's sequence (walk.py)
        assign({self.tol_acc: o.residual_tol, self.roundoff: 16 * np.finfo(model.real).eps,
                self.end.energy_tol: 1e3 * np.finfo(model.real).eps,
                self.objective.friction_velocity: o.friction_velocity,
                self.objective.translation_free: not terrain.has_contact and not (model.mass_np <= 0).any(),
                self.max_iters: o.max_iterations, self.ls_iters: o.line_search_iters,
                self.max_updates: o.friction_updates, self.cg_iters: o.cg_iters, self.cg_tol: o.cg_tol,
                self.ew_forcing: o.eisenstat_walker, self.velocity_tol: o.velocity_tol,
                # The energy account assumes no pinned particle does work on the body.
                self.end.clamp_on: o.energy_clamp and not np.any(model.mass_np <= 0),
                self.contact.release_tol: max(o.residual_tol, 0.1)})
        self._masses_changed = True  # (notify_model_changed) total mass and translation test to refresh
        self.in_kernel = InKernel(self)  # the serial driver's phases
        self.launches = Launches(self)  # the parallel driver's

    # Body-body contact lives inside the step (pairs.py): ``contacts`` given at construction
    # (Simulation gives its own, for a scene with several bodies) builds the pair terms; None builds
    # none, so a one-body scene compiles no pair code. The explicit methods' pass after the step is
    # not run.
    @property
    def contacts(self):
        return self._contacts

    @contacts.setter
    def contacts(self, value):
        self._contacts = value
        self.pairs = None
        if value is not None and self.options.body_contact:
            self.pairs = PairContacts(self.model, self.terrain, self.sc, self.objective,
                                      self.options.contact_stiffness)
        self.objective.pairs = self.end.pairs = self.pairs

    def _has_pairs(self) -> bool:
        return self.pairs is not None

    @ti.func
    def grab_factored(self, i):
        """Whether the solver's matrix already carries the grab on particle i (operator.py;
        fast_mass_spring's factor does); otherwise a grabbed particle counts as held (objective.py)."""
        return False

    @ti.func
    def _body_contacts(self, x: ti.template(), v: ti.template(), dt):
        pass  # inside the step (pairs.py)

    def _prepare(self, dt: float):
        """Hook run before each ``advance`` with its dt [s] (fast mass-spring refactorises here)."""

    # -- phase 1: begin ---------------------------------------------------------------------------
    @ti.func
    def _begin_step(self, x: ti.template(), v: ti.template(), dt):
        """Start a step of h = dt: the scheme (scheme.py) sets yd, u_base and h_eff, the step every
        term of the objective uses (h, or 2 h / 3 for BDF2)."""
        m = self.model
        self.scheme.choose(x, v, dt, self.objective.x_prev, self.objective.v_prev, self.objective.yd,
                           ti.static(self._has_pairs() or self.model.has_grab()))
        he = self.scheme.h_eff[None]
        self.sc.h2_prev[None] = self.objective.h2[None]  # the multipliers kept in lam are for this h^2
        self.objective.h2[None] = he * he
        self.tol2[None] = (self.tol_acc[None] * he * he) ** 2 * self.objective.total_mass[None]
        self.objective.fric_eps[None] = self.objective.friction_velocity[None] * he
        for s in range(m.n_springs):
            # The damper direction, frozen over the step: at x_n for backward Euler (a first-order
            # lag, like the method); at the predictor y = x_{n+1} + O(h^2) for BDF2 and SDIRK2's
            # stages, or the lag alone would make them first order.
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            d = x[a] - x[b]
            if self.scheme.bdf2_step[None] or self.scheme.stage[None] == 1 or self.scheme.stage[None] == 2:
                d += self.objective.yd[a] - self.objective.yd[b]
            length = d.norm()
            self.objective.spring_dir[s] = d / length if length > 0 else ti.Vector.zero(float, 3)
        self.sc.t_max[None] = 1.0
        self.sc.k_start[None] = 0.0
        for i in range(self.n):
            xi = x[i]
            self.objective.x_prev[i] = xi
            self.objective.v_prev[i] = v[i]
            self.objective.u[i] = ti.Vector.zero(float, 3)
            self.objective.grad[i] = ti.Vector.zero(float, 3)
            self.objective.fric_hess[i] = ti.Matrix.zero(float, 3, 3)
            d = self.objective.yd[i]
            if self.model.free(i):
                mi = m.mass[i]
                self.sc.k_start[None] += 0.5 * mi * v[i].dot(v[i])
                if ti.static(self.terrain.has_contact):
                    d = self.contact.start(i, xi, d, he)
                self.objective.dx[i] = d
            else:
                self.objective.u[i] = d
                x[i] = xi + d  # pinned: moves with its own velocity, never solved for
                self.objective.dx[i] = ti.Vector.zero(float, 3)
                if ti.static(self.terrain.has_contact):
                    self.contact.release(i)
        if ti.static(self._has_pairs()):
            self.pairs.begin(self.objective.x_prev, self.objective.yd, self.objective.dx, self.objective.u, he)
        for c in ti.static(self._counters):
            c[None] = 0
        self.sc.res_prev[None] = 1e30  # no release before a residual is known
        self.sc.step[None] = 1e30
        self.accounts.begin_step()
        # Phase 0 evaluates the reference g(x_n) and E(x_n): one trial at alpha = 0.
        self._line_search_begin(0.0, 0)

    # -- the iteration's phases: the work and its decision -------------------------------------------
    @ti.func
    def _gradient(self, x: ti.template(), dt):
        """The gradient at x (and the linear operator's data), then the decision on it."""
        self.objective.gradient(x, dt)
        self._after_gradient(dt)

    @ti.func
    def _trial(self, x: ti.template(), dt):
        """g at the line search's trial point, then Armijo's decision on it."""
        self.objective.trial(x, dt)
        self._line_search_decide()

    # -- decisions ----------------------------------------------------------------------------------
    @ti.func
    def _line_search_begin(self, alpha, limit):
        self.sc.alpha[None] = alpha
        self.sc.ls_count[None] = 0
        self.sc.ls_limit[None] = limit
        self.sc.ls_done[None] = 0
        self.sc.accepted[None] = 0

    @ti.func
    def _line_search_decide(self):
        """Armijo (c = 1e-4, the objective's round-off tolerated) on the trial just evaluated; at the
        start grad = 0, so the test is g(x_0) <= g(x_n)."""
        f0 = self.sc.f_cur[None]
        if self.sc.phase[None] == 0:  # the reference point x_n itself
            self.sc.accepted[None] = 1
            self.sc.ls_done[None] = 1
        elif self.sc.f_trial[None] - f0 <= 1e-4 * self.sc.dec[None] + self.roundoff[None] * ti.abs(f0):
            self.sc.accepted[None] = 1
            self.sc.ls_done[None] = 1
        elif self.sc.ls_count[None] >= self.sc.ls_limit[None]:
            self.sc.ls_done[None] = 1
        else:
            self.sc.alpha[None] *= 0.5
            self.sc.ls_count[None] += 1
            if self.sc.phase[None] == 2:
                self.sc.backtracks[None] += 1

    @ti.func
    def _accept(self, x: ti.template()):
        """Move to the accepted trial; an iteration whose line search failed ends the step (x and its
        gradient stay valid). A rejected start leaves the step at x_n."""
        ok = self.sc.accepted[None]
        for i in range(self.n):
            if ok:
                x[i] = self.objective.x_trial[i]
                self.objective.u[i] = self.objective.u_trial[i]
                if ti.static(self.terrain.has_contact):
                    self.contact.accept(i)
        phase = self.sc.phase[None]
        if ok:
            self.sc.f_cur[None] = self.sc.f_trial[None]
            self.sc.e_cur[None] = self.sc.e_trial[None]
            self.sc.step[None] = self.sc.step_trial[None]
        elif phase == 2:
            self.sc.done[None] = 1
            self.sc.ls_failed[None] = 1  # no decrease along the direction while unconverged: counted
        if phase == 0:
            # The reference: g, spring and total energy at x_n; next, the feasible start.
            # Gravity energy is measured from x_n (0 here; -m g . u at the end): its absolute value,
            # m g y summed over the body, rounded away the balance of a step in f32.
            self.sc.h_start[None] = self.sc.k_start[None] + self.sc.e_trial[None]
            self.sc.h_scale[None] = self.sc.k_start[None] + self.sc.e_trial[None]
            if self.scheme.stage[None] == 1:
                self.scheme.h_step[None] = self.sc.h_start[None]
            elif self.scheme.stage[None] >= 2:
                # The account is the whole step's: its start energy, gravity measured from X1.
                self.sc.h_start[None] = self.scheme.h_step[None] + self.sc.g_stage[None]
            self._line_search_begin(self.sc.t_max[None], START_HALVINGS)
        self.sc.phase[None] = ti.min(phase + 1, 2)

    @ti.func
    def _after_gradient(self, dt):
        """Record the residual; decide: done, refreeze friction (re-evaluate), or iterate on (and set
        the CG forcing term)."""
        k = self.sc.evals[None]
        res = self.objective.residual()
        self.accounts.residual_at(k, res)
        self.sc.evals[None] = k + 1
        if k == 0:
            self.sc.res2_0[None] = self.sc.res2[None]
        self.sc.res_prev[None] = res
        was_update = self.sc.update[None]
        self.sc.update[None] = 0
        capped = self.sc.outer[None] >= self.max_iters[None]
        small = self.sc.outer[None] > 0 and was_update == 0 and self.sc.step[None] <= self.velocity_tol[None] * dt
        converged = self.sc.res2[None] <= self.tol2[None] or small
        # Refreeze the friction multipliers (bounded): at convergence if they moved by more than 10 %,
        # or at once if they are mostly stale -- but not at the step's first gradient, at the start
        # point (the predictor), which over-counts the load the warm-started multipliers carry. (A
        # particle held since the last freeze gets its first multiplier at its first gradient.)
        change = self.sc.lam_change[None]
        stale = k > 0 and change > 0.5 * self.sc.lam_sum[None] + 1e-300
        moved = change > 0.1 * self.sc.lam_sum[None] + 1e-300
        if (stale or (converged and moved)) and not capped and self.sc.updates[None] < self.max_updates[None]:
            self.sc.update[None] = 1
            self.sc.updates[None] += 1
        elif converged or capped:
            self.sc.done[None] = 1
        tol = self.cg_tol[None]
        if self.ew_forcing[None]:
            ratio = ti.sqrt(ti.sqrt(self.sc.res2[None] / ti.max(self.sc.res2_0[None], 1e-300)))
            tol = ti.min(0.5, ratio)
        self._set_cg_tol(tol)

    @ti.func
    def _set_cg_tol(self, tol):
        self.pcg.rel_tol[None] = tol

    @ti.func
    def _bounce_rhs(self):
        """The restitution spread's system (restitution.py), solved to ``BOUNCE_CG_TOL``."""
        self.spread.set_rhs(self)
        self.pcg.rel_tol[None] = BOUNCE_CG_TOL

    @ti.func
    def _after_direction(self):
        self.sc.outer[None] += 1
        self._line_search_begin(1.0, self.ls_iters[None])

    # -- the drivers: one source (walk.py), run inside the serial kernel or from Python scope -----
    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        self.step_walk.func(self, self.in_kernel, x, v, dt, step)

    def _advance_parallel(self, state, dt: float, n_steps: int) -> int:
        """``n_steps`` steps of ``dt`` [s], one launch per phase; returns the steps taken (to divergence)."""
        start = self._step_counter
        for k in range(n_steps):
            self.step_walk.py(self, self.launches, state.x, state.v, dt, start + k)
            if self.diverged:
                break
        self._step_counter += n_steps
        bad = int(self.diverged_step[None])
        return bad - start + 1 if self.diverged else n_steps

    @ti.pyfunc
    def _stage_dt(self, stage, dt):
        """The time [s] solve ``stage`` of a step of ``dt`` covers: all of it (one solve a step), or
        SDIRK2's gamma h (stage 0), then (1 - gamma) h (stage 1, and 2: stage 1 taken again)."""
        out = dt
        if self.stages > 1:
            out = SDIRK_GAMMA * dt if stage == 0 else (1.0 - SDIRK_GAMMA) * dt
        return out

    @ti.func
    def _restore_stage(self, x: ti.template(), v: ti.template()):
        """Back to the first stage's end (X1, V1: the second stage's start, kept by the objective)."""
        for i in range(self.n):
            x[i] = self.objective.x_prev[i]
            v[i] = self.objective.v_prev[i]

    def _serial_ir_passes(self) -> bool:
        # With body pairs the one-launch step is several times the one-body kernel, and Taichi's IR
        # passes on it take most of its compile (docs/decisions/serial-step-ir-passes.md).
        return self.pairs is None

    # -- public API -----------------------------------------------------------------------------------
    def advance(self, state, dt: float, n_steps: int) -> int:
        self._sync_masses()
        self._prepare(self._stage_dt(0, dt))  # both SDIRK2 stages solve over gamma h
        if self._serial() or n_steps <= 0 or self.diverged:
            return super().advance(state, dt, n_steps)
        return self._advance_parallel(state, dt, n_steps)

    def notify_model_changed(self, flags: int):
        super().notify_model_changed(flags)
        if flags & CHANGED_MASSES:
            self._masses_changed = True

    def _sync_masses(self):
        """Total free mass [kg] into its field when the masses changed (``Model.set_particle_mass``,
        ``set_masses``: pinning one ends the step's translation invariance)."""
        if self._masses_changed:
            mass = self.model.mass_np
            assign({self.objective.total_mass: float(np.sum(mass[mass > 0])) or 1.0,
                    self.objective.translation_free: not self.terrain.has_contact and not (mass <= 0).any()})
            self._masses_changed = False

    def reset(self):
        super().reset()
        self.accounts.reset()
        self.contact.reset()  # no warm start from before the reset
        if self.pairs is not None:
            self.pairs.reset()
        self.scheme.reset()  # BDF2 starts its history again

    def residual(self) -> float:
        """Residual [m/s^2] of the last gradient evaluation (``Objective.residual``, in the run's precision)."""
        return float(self._residual())

    @ti.kernel
    def _residual(self) -> float:
        return self.objective.residual()

    def residual_history(self) -> list[float]:
        """Residual [m/s^2] at each gradient evaluation of the last step (the first at the start)."""
        return self.accounts.history()
