"""Force evaluation shared by every integrator: gravity, Hooke springs, dampers, contact, friction.

Spring on particle a (seed):  f_a = -ks (|x_a - x_b| - r) l,  l = (x_a - x_b) / |x_a - x_b|
Damper on particle a (seed):  f_a = -kd ((v_a - v_b) . l) l

``spring_force`` is the one formula; ``ForceEvaluator`` evaluates it two ways:

* ``compute(x, v, dt, a)``: the general reference pass, a[i] for every particle, reading each
  spring's stiffness through its group (``model.group_k``). Tests and tools use it.
* the step kernels' pieces (``spring_pass`` + ``accel``): the same forces with each spring's
  (k, kd) copied next to it (per spring, or per slot of the gather's padded rows, rows.py), so the
  inner loop has no group indirection, and no acceleration buffer: an integrator turns
  ``accel(x, v, i, dt)`` into the new state of particle i in the same loop. The copies are
  refreshed from ``model.group_k`` / ``group_kd`` by ``refresh()`` (at the top of every step
  kernel) when those fields changed, so a stiffness changed at run time (the demo's sliders, the
  stability sweep) acts on the next step.
"""

import numpy as np
import taichi as ti

from .footprint import Buffers, FieldCounts
from .spring_codes import end_b_spring
from .rows import SpringRows

# Added to a spring's length before dividing by it: a zero-length spring then has direction 0
# (and no force) instead of NaN, with no branch in the spring loop (a branch there keeps LLVM
# from vectorising the gather loop: docs/benchmarks/README.md, "Speed: why the engine was slower").
# Below every real length's rounding (f32: lengths above ~1e-22 m are unchanged), and its
# inverse is finite in f32, so fast math's no-inf assumption holds.
TINY = 1e-30


@ti.func
def spring_force(d, dv, length, rest, k, kd):
    """Spring + damper force [N] on end a of a spring, from d = x_a - x_b [m] (``length`` = |d|)
    and dv = v_a - v_b [m/s]; ``k`` [N/m], ``kd`` [N s/m], ``rest`` [m]. Zero length: no force."""
    l = d * (1.0 / (length + TINY))
    return -(k * (length - rest) + kd * dv.dot(l)) * l


@ti.func
def spring_pair_force(x: ti.template(), v: ti.template(), a, b, rest, k, kd):
    """Spring + damper force [N] on particle a from its spring to b (b gets the opposite).

    ``k`` [N/m] stiffness, ``kd`` [N s/m] damper coefficient, ``rest`` [m] rest length.
    """
    d = x[a] - x[b]
    return spring_force(d, v[a] - v[b], d.norm(), rest, k, kd)


@ti.func
def gather_spring_force(model: ti.template(), x: ti.template(), v: ti.template(), i):
    """Sum of spring and damper forces [N] on particle i, from i's adjacency list (group lookup)."""
    f = ti.Vector.zero(float, 3)
    for e in range(model.adj_offset[i], model.adj_offset[i + 1]):
        g = model.adj_group[e]
        f += spring_pair_force(x, v, i, model.adj_other[e], model.adj_rest[e], model.group_k[g], model.group_kd[g])
    return f


@ti.func
def _damper_pair_force(x: ti.template(), dv: ti.template(), a, b, kd):
    """Damper force [N] on particle a from its spring to b at velocities ``dv`` [m/s] (no stiffness)."""
    d = x[a] - x[b]
    return spring_force(d, dv[a] - dv[b], d.norm(), 0.0, 0.0, kd)


STRATEGIES = ("scatter", "per_spring", "gather")


def auto_strategy(arch: str, fast_math: bool, stencil: bool = False) -> str:
    """The force strategy ``forces = "auto"`` picks on backend ``arch`` ("cpu", "cuda", ...);
    ``stencil``: whether the stencil pass may run (every body a cube, parallel launches, f64, a
    method that does not read the stored springs).

    GPU: gather (the scatter's slab passes would run one slab per thread; the stencil not measured
    there). CPU with fast math: the stencil where allowed, as fast as the gather's padded rows or
    faster with a fifth of their memory per particle (in f32, and for serial launches and mesh
    bodies, the gather was faster); else the gather, whose rows LLVM vectorises:
    1.5x the scatter at one thread in f32, as fast in f64 at n = 40 (``rows_look_up_groups``),
    no slab passes (docs/decisions/auto-picks-the-stencil.md; docs/benchmarks/README.md, "Speed").
    CPU without fast math: nothing vectorises; the scatter (each spring once) is 1.3x the gather.
    """
    if arch != "cpu":
        return "gather"
    if not fast_math:
        return "scatter"
    return "stencil" if stencil else "gather"


def rows_look_up_groups(real_bytes: int) -> bool:
    """Whether the gather's rows read each slot's (k, kd) through its group (f64) instead of a
    per-slot copy (f32). ``studies/kernel_study.py``, n = 40, one thread (docs/benchmarks/README.md),
    against the plain CSR kernel: f64 copies 0.74x, lookups 1.17x (16 bytes a slot of copies);
    f32 copies 1.18x, lookups 1.07x (the two extra gathers cost more than 8 bytes save)."""
    return real_bytes == 8


def pass_buffers(strategy: str, counts, real_bytes: int) -> Buffers:
    """What a fused ``ForceEvaluator`` of ``strategy`` allocates for ``counts`` (footprint.Counts)
    with reals of ``real_bytes``: scatter: force sums | (k, kd); gather: the padded rows (rows.py),
    per slot 2 ints, the rest length and, without group lookups (f32), the (k, kd) copy.
    ``per_spring`` is counted as scatter, its close upper bound."""
    if strategy == "gather":
        slots = counts.particles * counts.row_width
        return Buffers(reals=(1 if rows_look_up_groups(real_bytes) else 3) * slots, ints=2 * slots)
    return Buffers(FieldCounts(3, 0, 2, 0))

# Iterations between two slabs of the parallel scatter's loop: at least the largest task Taichi
# 1.7's CPU backend makes (1024, ``cpu_block_dim_adaptive``), so no task holds two slabs' work.
SLAB_STRIDE = 1024


@ti.data_oriented
class ForceEvaluator:
    """Evaluates every particle's acceleration [m/s^2] from gravity, springs, dampers and contact.

    Three strategies give the same forces (to rounding: they sum a particle's springs in
    different orders):

    * ``scatter``: one pass over springs evaluates each spring once and adds its force to both
      ends' force sums with plain (non-atomic) adds; the particle pass reads and clears its sum.
      Serial launches run the springs in one loop. Parallel launches run the slabs of
      ``slabs.py`` (ranges of the model's own spring ids; no copy of the springs): the even
      slabs in parallel, then the odd ones, so no two threads ever add to the same particle.
      The fastest on the CPU without fast math (``auto_strategy``); needs no adjacency.
    * ``per_spring``: one pass over springs stores each spring's force once, then each particle
      sums its springs' forces (signed by which end it is).
    * ``gather``: each particle evaluates all of its springs itself (every spring twice), over
      its padded row (rows.py: constant trip count, no branch, so LLVM vectorises it). One
      loop, no shared buffer and no atomics. A step built on it must read the old state and
      write the new one to other buffers (ping-pong). The fastest with fast math and on GPUs.

    ``parallel``: the step runs in parallel launches (scatter then uses its slab passes).
    ``fused=False`` (reference evaluators in tests and tools) allocates nothing for the step
    kernels, only what ``compute`` needs.
    """

    def __init__(self, model, terrain, strategy: str = "per_spring", fused: bool = True, parallel: bool = False):
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown force strategy {strategy!r}")
        if strategy == "scatter" and not fused:
            strategy = "per_spring"  # compute() has no scatter path
        self.model = model
        self.terrain = terrain
        self.strategy = strategy
        self.parallel = parallel
        self.rows = None
        model.ensure_springs()  # every strategy here reads the stored springs
        if fused and strategy == "gather":
            # padded rows (rows.py); compute() walks them too
            self.rows = SpringRows(model, copies=not rows_look_up_groups(np.dtype(model.real).itemsize))
        elif not (fused and strategy == "scatter"):
            model.ensure_adjacency()  # per_spring sums, and compute(), walk each particle's springs
        m = max(model.n_springs, 1)
        self.spring_f = ti.Vector.field(3, float, m) if strategy == "per_spring" else None
        # (k [N/m], kd [N s/m]) of each spring (per_spring, scatter); gather: ``rows.kkd`` per slot.
        self.kkd = None
        if fused and strategy != "gather":
            self.kkd = ti.Vector.field(2, float, m)
        # refresh(): group_k, group_kd as last copied; whether a copy was made; whether one is due
        self._seen = ti.Vector.field(2, float, max(model.n_groups, 1))
        self._copied = ti.field(ti.i32, ())
        self._changed = ti.field(ti.i32, ())
        if strategy == "scatter":
            self.f = ti.Vector.field(3, float, model.n_particles)  # per-particle force sums [N], kept at 0 between passes
            first, ranges = model.slab_ranges()  # the model's own springs, split into slabs (slabs.py)
            self.n_slabs = len(first) - 1
            self.slab_first = ti.field(ti.i32, len(first))
            self.slab_first.from_numpy(first)
            self.slab_range = ti.Vector.field(2, ti.i32, max(len(ranges), 1))
            if len(ranges):
                self.slab_range.from_numpy(ranges)

    def _has_rows(self) -> bool:
        return self.rows is not None

    def _row_copies(self) -> bool:  # the gather's rows hold (k, kd) copies (else: group lookups)
        return self._has_rows() and self.rows.copies

    def _keeps_copies(self) -> bool:  # (k, kd) copies per spring or per slot of the rows, for refresh
        return self.kkd is not None or self._row_copies()

    # -- parameter copies ----------------------------------------------------------------------
    @ti.func
    def refresh(self):
        """Copy the groups' stiffness and damping into the per-spring (or per-slot) copies if they
        changed since the last copy (also when written straight into the fields). At the top of
        every step kernel: a serial comparison of the few groups, then a copy loop of zero
        iterations unless something changed (from Python before each ``advance`` it downloaded both
        fields, most of the ``run`` path's per-frame cost at n = 10; docs/benchmarks)."""
        if ti.static(self._keeps_copies()):  # f64 rows read the groups themselves: nothing to keep
            m = self.model
            ti.loop_config(serialize=True)
            for g in range(m.n_groups):
                kkd = ti.Vector([m.group_k[g], m.group_kd[g]])
                if kkd[0] != self._seen[g][0] or kkd[1] != self._seen[g][1] or self._copied[None] == 0:
                    self._changed[None] = 1
                    self._seen[g] = kkd
            self._copied[None] = 1
            # Serial even in parallel launches: an empty parallel loop still costs a thread-pool round
            # trip every step, and a change (a slider move) is rare; copying then takes a few ms.
            if ti.static(self._row_copies()):
                rows = self.rows
                ti.loop_config(serialize=True)
                for e in range(self._changed[None] * m.n_particles * rows.width):
                    g = rows.group[e]
                    rows.kkd[e] = ti.Vector([m.group_k[g], m.group_kd[g]])  # padding: zero force anyway
            else:  # per-spring copies
                ti.loop_config(serialize=True)
                for s in range(self._changed[None] * m.n_springs):
                    g = m.spring_group[s]
                    self.kkd[s] = ti.Vector([m.group_k[g], m.group_kd[g]])
            self._changed[None] = 0

    # -- step-kernel pieces ---------------------------------------------------------------------
    @ti.func
    def spring_pass(self, x: ti.template(), v: ti.template()):
        """per_spring only: store every spring's force [N] (a top-level loop); gather: nothing."""
        m = self.model
        if ti.static(self.strategy == "per_spring"):
            for s in range(m.n_springs):
                ends = m.spring_ends[s]
                kkd = self.kkd[s]
                self.spring_f[s] = spring_pair_force(x, v, ends[0], ends[1], m.spring_rest[s], kkd[0], kkd[1])
        elif ti.static(self.strategy == "scatter" and self.parallel):
            self._slab_scatter(x, v, False)
        elif ti.static(self.strategy == "scatter"):
            for s in range(m.n_springs):
                self._scatter(x, v, s)

    @ti.func
    def _slab_scatter(self, x: ti.template(), v: ti.template(), dampers_only: ti.template()):
        """scatter, parallel: every spring's force (with ``dampers_only``, compile-time: its damper
        alone at velocities ``v``) added to both ends' sums, slab by slab (top-level loops)."""
        for parity in ti.static(range(2)):
            # Slabs of one parity share no particle, so each may run on its own thread. Taichi
            # 1.7's CPU backend gives every task of a parallel loop at least 512 iterations
            # (``cpu_block_dim_adaptive``, which overrides ``loop_config(block_dim=...)``), so a
            # loop over the few slabs would run on one thread: slab k is iteration
            # k * SLAB_STRIDE of a longer loop whose other iterations do nothing.
            for t in range((self.n_slabs - parity + 1) // 2 * SLAB_STRIDE):
                if t % SLAB_STRIDE == 0:
                    slab = 2 * (t // SLAB_STRIDE) + parity
                    for r in range(self.slab_first[slab], self.slab_first[slab + 1]):
                        for s in range(self.slab_range[r][0], self.slab_range[r][1]):
                            if ti.static(dampers_only):
                                self._scatter_damper(x, v, s)
                            else:
                                self._scatter(x, v, s)

    @ti.func
    def _scatter(self, x: ti.template(), v: ti.template(), s):
        """Add spring s's force to both ends' sums (plain adds: see the class docstring)."""
        ends = self.model.spring_ends[s]
        kkd = self.kkd[s]
        f = spring_pair_force(x, v, ends[0], ends[1], self.model.spring_rest[s], kkd[0], kkd[1])
        self.f[ends[0]] = self.f[ends[0]] + f
        self.f[ends[1]] = self.f[ends[1]] - f

    @ti.func
    def accel(self, x: ti.template(), v: ti.template(), i, dt):
        """Acceleration [m/s^2] of particle i at state (x, v), once per particle and pass;
        per_spring and scatter need ``spring_pass`` first."""
        return self.particle_accel(x, v, i, self.spring_sum(x, v, i), dt)

    @ti.func
    def _row_force(self, x: ti.template(), v: ti.template(), i, lookup: ti.template()):
        """gather: spring force sum [N] on particle i over its padded row (rows.py); (k, kd) from
        the slot's copy, or with ``lookup`` (compile-time) from its group. No branch in the loop and a constant
        trip count: LLVM vectorises it (with fast math, which lets it reorder the sum)."""
        rows = self.rows
        w = ti.static(rows.width)
        xi, vi = x[i], v[i]
        f = ti.Vector.zero(float, 3)
        for k in range(w):
            e = i * w + k
            j = rows.other[e]
            d = xi - x[j]
            kkd = ti.Vector.zero(float, 2)
            if ti.static(lookup):
                kkd = ti.Vector([self.model.group_k[rows.group[e]], self.model.group_kd[rows.group[e]]])
            else:
                kkd = rows.kkd[e]
            f += spring_force(d, vi - v[j], d.norm(), rows.rest[e], kkd[0], kkd[1])
        return f

    @ti.func
    def spring_sum(self, x: ti.template(), v: ti.template(), i):
        """Spring and damper force sum [N] on particle i at state (x, v), without gravity or contact
        (``accel``'s sum; per_spring and scatter need ``spring_pass`` first, and scatter clears it)."""
        m = self.model
        f = ti.Vector.zero(float, 3)
        if ti.static(self.strategy == "per_spring"):
            # Two branch-free runs: springs where i is end a (+f), then end b (-f).
            for e in range(m.adj_offset[i], m.adj_split[i]):
                f += self.spring_f[m.adj_spring[e]]
            for e in range(m.adj_split[i], m.adj_offset[i + 1]):
                f -= self.spring_f[end_b_spring(m.adj_spring[e])]
        elif ti.static(self.strategy == "scatter"):
            f = self.f[i]
            self.f[i] = ti.Vector.zero(float, 3)  # ready for the next pass
        else:
            f = self._row_force(x, v, i, ti.static(not self._row_copies()))
        return f

    # -- the damper alone (velocity Verlet's corrector) -------------------------------------------
    @ti.func
    def damper_pass(self, x: ti.template(), dv: ti.template()):
        """``spring_pass`` for the dampers alone at velocities ``dv`` [m/s] (the springs' stiffness
        left out): each spring's direction at ``x`` and the relative velocity of its ends. The damper
        is linear in the velocity, so a force at v plus this one at dv is the force at v + dv."""
        m = self.model
        if ti.static(self.strategy == "per_spring"):
            for s in range(m.n_springs):
                ends = m.spring_ends[s]
                self.spring_f[s] = _damper_pair_force(x, dv, ends[0], ends[1], self.kkd[s][1])
        elif ti.static(self.strategy == "scatter" and self.parallel):
            self._slab_scatter(x, dv, True)
        elif ti.static(self.strategy == "scatter"):
            for s in range(m.n_springs):
                self._scatter_damper(x, dv, s)

    @ti.func
    def _scatter_damper(self, x: ti.template(), dv: ti.template(), s):
        ends = self.model.spring_ends[s]
        f = _damper_pair_force(x, dv, ends[0], ends[1], self.kkd[s][1])
        self.f[ends[0]] = self.f[ends[0]] + f
        self.f[ends[1]] = self.f[ends[1]] - f

    @ti.func
    def damper_sum(self, x: ti.template(), dv: ti.template(), i):
        """Damper force sum [N] on particle i at velocities ``dv`` (after ``damper_pass``)."""
        f = ti.Vector.zero(float, 3)
        if ti.static(self._has_rows()):
            rows = self.rows
            w = ti.static(rows.width)
            xi, vi = x[i], dv[i]
            for k in range(w):
                e = i * w + k
                j = rows.other[e]
                kd = 0.0
                if ti.static(not self._row_copies()):
                    kd = self.model.group_kd[rows.group[e]]
                else:
                    kd = rows.kkd[e][1]
                d = xi - x[j]
                f += spring_force(d, vi - dv[j], d.norm(), 0.0, 0.0, kd)
        else:
            f = self.spring_sum(x, dv, i)
        return f

    # -- shared ------------------------------------------------------------------------------------
    @ti.func
    def particle_accel(self, x: ti.template(), v: ti.template(), i, f_springs, dt):
        """Acceleration of particle i given its spring force sum; adds gravity, the grab (if the
        model has one, ``grab.py``) and contact."""
        m = self.model
        f = f_springs
        if ti.static(m.has_grab()):
            f += m.grab.force(i, x[i], v[i])
        a = m.gravity[None] * ti.cast(m.inv_mass[i] > 0, float) + f * m.inv_mass[i]
        if ti.static(self.terrain.has_contact):
            a = self.terrain.contact_accel(i, x[i], v[i], a, dt)
        return a

    @ti.func
    def compute(self, x: ti.template(), v: ti.template(), dt, a: ti.template()):
        """a[i] = acceleration of every particle at state (x, v). ``dt`` [s] caps friction.

        The general reference pass (group lookups, an acceleration buffer); an evaluator made
        with ``fused=False`` or a gathering strategy has it (a fused scatter one has no
        adjacency to gather over). Contains top-level
        loops: called from a kernel's top level they run in parallel, inside a serial loop serially.
        """
        m = self.model
        if ti.static(self.strategy == "per_spring"):
            for s in range(m.n_springs):
                ends = m.spring_ends[s]
                g = m.spring_group[s]
                self.spring_f[s] = spring_pair_force(x, v, ends[0], ends[1], m.spring_rest[s], m.group_k[g], m.group_kd[g])
            for i in range(m.n_particles):
                a[i] = self.accel(x, v, i, dt)  # sums the stored spring forces
        elif ti.static(self._has_rows()):
            for i in range(m.n_particles):
                a[i] = self.particle_accel(x, v, i, self._row_force(x, v, i, True), dt)
        else:
            for i in range(m.n_particles):
                a[i] = self.particle_accel(x, v, i, gather_spring_force(m, x, v, i), dt)


@ti.data_oriented
class Diagnostics:
    """Reductions over a state: energies [J], centre of mass [m], speeds, terrain distance."""

    def __init__(self, model, terrain):
        self.model = model
        self.terrain = terrain
        self.out = ti.field(ti.f64, 8)
        if model.stencil is None:
            model.ensure_springs()  # the spring energy sums the stored springs, or the stencil's

    @ti.kernel
    def _reduce(self, x: ti.template(), v: ti.template()):
        m = self.model
        for k in range(8):
            self.out[k] = 0.0
        self.out[5] = -1e300
        self.out[6] = 1e300
        for i in range(m.n_particles):
            mi = ti.cast(m.mass[i], ti.f64)
            vi = ti.cast(v[i], ti.f64)
            xi = ti.cast(x[i], ti.f64)
            self.out[0] += 0.5 * mi * vi.dot(vi)
            self.out[1] += -mi * ti.cast(m.gravity[None], ti.f64).dot(xi)
            self.out[2] += mi * xi.x
            self.out[3] += mi * xi.y
            self.out[4] += mi * xi.z
            ti.atomic_max(self.out[5], vi.norm())
            if ti.static(self.terrain.has_contact):
                d, _ = self.terrain.query(i, x[i])
                ti.atomic_min(self.out[6], ti.cast(d, ti.f64))
        if ti.static(m.springs_stored()):
            for s in range(m.n_springs):
                a, b = m.spring_ends[s][0], m.spring_ends[s][1]
                stretch = ti.cast((x[a] - x[b]).norm() - m.spring_rest[s], ti.f64)
                self.out[7] += 0.5 * ti.cast(m.group_k[m.spring_group[s]], ti.f64) * stretch * stretch
        else:
            m.stencil.add_spring_energy(x, self.out, 7)

    def compute(self, state) -> dict:
        """Energies [J], centre of mass [m], max speed [m/s], min signed terrain distance [m]."""
        self._reduce(state.x, state.v)
        o = self.out.to_numpy()
        total_mass = float(self.model.mass_np.sum())
        kinetic, gravity, spring = float(o[0]), float(o[1]), float(o[7])
        return {
            "kinetic_energy": kinetic,
            "gravity_energy": gravity,
            "spring_energy": spring,
            "potential_energy": gravity + spring,
            "total_energy": kinetic + gravity + spring,
            "center_of_mass": [float(o[2]) / total_mass, float(o[3]) / total_mass, float(o[4]) / total_mass],
            "max_speed": float(o[5]),
            "min_terrain_distance": float(o[6]) if self.terrain.has_contact else None,
        }


# -- spring energy and its derivatives (implicit integrators) -----------------------------------
@ti.func
def spring_energy(model: ti.template(), x: ti.template(), a, b, rest, g):
    """Elastic energy [J] of the spring between particles a and b: E = k/2 (|x_a - x_b| - r)^2."""
    stretch = (x[a] - x[b]).norm() - rest
    return 0.5 * model.group_k[g] * stretch * stretch


@ti.func
def spring_energy_derivatives(model: ti.template(), x: ti.template(), a, b, rest, g):
    """Gradient [N] of the spring energy w.r.t. x_a (x_b's is its negative) and its 3x3 Hessian block [N/m].

    The gradient is written as in the local step of Liu et al. 2013: with the projected spring
    d = r (x_a - x_b) / |x_a - x_b|, dE/dx_a = k ((x_a - x_b) - d) = k (|x_a - x_b| - r) l, i.e.
    minus the Hooke force of ``spring_pair_force``. The Hessian block
    H = k (l l^T + (1 - r/|x_a - x_b|) (I - l l^T)) is made positive semi-definite by clamping
    the transverse factor (1 - r/|x_a - x_b|) at zero under compression (Choi & Ko 2002), so
    Newton directions stay descent directions. The full Hessian couples a and b as [[H, -H], [-H, H]].
    A zero-length spring has no direction and contributes nothing, as in ``spring_pair_force``.
    """
    grad = ti.Vector.zero(float, 3)
    hess = ti.Matrix.zero(float, 3, 3)
    d = x[a] - x[b]
    length = d.norm()
    if length > 0:
        k = model.group_k[g]
        l = d * (1.0 / length)
        target = rest * l  # Liu et al. 2013 local step: the rest-length spring closest to d
        grad = k * (d - target)
        llt = l.outer_product(l)
        hess = k * (llt + ti.max(1.0 - rest / length, 0.0) * (ti.Matrix.identity(float, 3) - llt))
    return grad, hess
