"""The constant matrix A = M + L of a step, L the springs' graph Laplacian with weights
c_s = h^2 k_s + h kd_s [kg] (the same for x, y and z: A (x) I3), prefactorised by a skyline
Cholesky when asked.

``fast_mass_spring``'s global step solves with it (docs/implicit.md). A depends on dt, the
stiffnesses, the damper coefficients and the masses only, so it is refactorised when one of them
changes (``factorizations`` counts them), never per iteration. (Tried as the coarse solve of a
two-level preconditioner for ``implicit_euler``'s PCG: 3-4x fewer CG iterations, but each cost
~6x a block-Jacobi one on a CPU, so Newton got 1.6-1.9x slower; not kept.)
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import STATE, Buffers, FieldCounts, per_particle
from ...linalg import SkylineCholesky
from ...model import CHANGED_MASSES, CHANGED_SPRINGS

CHOLESKY_AUTO_MAX = 10_000_000  # largest factor envelope [values] an "auto" option factorises
CHOLESKY_INDEX = FieldCounts(3, 2, 0, 0)  # linalg.SkylineCholesky: tmp, start, offset (+ the envelope's values)


def cholesky_pays(arch: str, counts) -> bool:
    """Whether "auto" factorises A on backend ``arch`` for ``counts`` (footprint.Counts): on a CPU
    (the triangular solves are serial, so on a GPU PCG wins) while the envelope holds at most
    CHOLESKY_AUTO_MAX values (asked for only on a CPU). The envelope grows like N^(5/3) for a cube
    (N particles), factorising like N^(7/3): the 20^3 cube has 6.4e6 values; the 40^3 one 2e8,
    1.6 GB in f64 and an hour-long factorisation."""
    return arch == "cpu" and counts.envelope <= CHOLESKY_AUTO_MAX


# global_solver = by_stiffness factorises A but takes the Jacobi-PCG global step, free flight and
# contact alike, above this h^2 k_max / m_min. On the five drops of the default cube at 1/30 s the
# Jacobi PCG step took 1.31x the factor's time at x1 (h^2 k / m = 2.2), 0.36x / 0.39x / 0.77x at
# x10 / x100 / x1000 (under contact on stiff springs the factor is only a PCG preconditioner, one
# serial pair of triangular solves per CG iteration). Not what auto picks: a cube pushed across the
# plane at x1000 then failed its line search on 46 of 120 steps at 1/30 s and slid 0.76 m instead
# of Coulomb's 1.53 m (docs/benchmarks/IMPLICIT.md).
FACTOR_MAX_STIFFNESS = 10.0
FACTORISED = ("cholesky", "by_stiffness")  # resolved global_solver values that factorise A


# contact_solve = auto picks the scaled contact step up to this h^2 k_max / m_min, PCG above. A 3^3
# cube (1 kg particles) pushed across the plane at 3 m/s should slide v^2 / (2 mu g) = 1.53 m; with
# the scaled step it slid 1.48 / 0.34 / 0.22 m at h^2 k / m = 6.7 / 22 / 17 (x3 and x10 at 1/30 s,
# x30 at 1/60 s), with PCG 1.45 / 1.42 / 1.40 m; at x1000 0.009 m against 1.47 m (1/30 s). The
# default cube at 1/30 s has 2.2: scaled, as before.
SCALED_CONTACT_MAX_STIFFNESS = 10.0

@ti.data_oriented
class LaplacianMatrix:
    """A = M + L and its factorisation, chosen by the ``global_solver`` option: a part of
    ``fast_mass_spring``.

    Inputs, given at construction: the ``model`` (masses, spring groups' k and kd, the spring
    graph; it listens to the model's changes) and the options it was built for; per ``prepare``,
    the step dt. Outputs, for the solver's global step: ``diag`` (A's diagonal), ``group_c`` (the
    off-diagonal weights per spring group), the factor ``chol`` (None without one) and this step's
    choices ``jacobi_now`` and ``scaled_now``.
    """

    BUFFERS = {"diag": per_particle("diagonal of M + L [kg] (0 for pinned particles)")}

    @staticmethod
    def buffers(options, counts, real_bytes, later: FieldCounts) -> Buffers:
        """The factor (index fields, the envelope's values) when it factorises; and the host bytes
        above the fields while the envelope is sized: the downloaded spring ends (8 bytes per
        spring), their min and max (4 + 4) and per-particle starts (16 bytes), at a moment after the
        model's fields and before the integrator's own (``later``, per particle and spring) and the
        state's, so only what exceeds those (counted whatever the choice, as ``auto`` sizes it to
        choose: 0 for every lattice). Its ``BUFFERS`` are the integrator's to count."""
        out = Buffers(FieldCounts())
        if options.global_solver in FACTORISED:
            out = out + Buffers(CHOLESKY_INDEX, reals=counts.envelope)
        later_bytes = (later + STATE).bytes(counts.particles, counts.springs, real_bytes)
        return out + Buffers(transient=max(0, 16 * counts.springs + 16 * counts.particles - later_bytes))

    def __init__(self, model, global_solver: str, contact_auto: bool):
        """Allocates its fields (a factor's index arrays are filled at once, as before)."""
        self.model = model
        self.n = model.n_particles
        allocate(self, self.BUFFERS, self.n, 0)
        self.group_c = ti.field(float, model.n_groups)  # Laplacian weight h^2 k + h kd [kg]
        self.factorised = global_solver in FACTORISED  # a compile-time constant
        self.chol = SkylineCholesky(model.n_particles, model.pairs_np) if self.factorised else None
        self._matrix_dt = None  # the dt [s] A was built for; None: rebuild (the model changed)
        self.factorizations = 0
        # 1: the scaled contact step this step (contact_solve = scaled; with auto, while the springs
        # are soft at this step, h^2 k_max / m_min <= SCALED_CONTACT_MAX_STIFFNESS). Set with A, when
        # dt or the model changed; contact_auto is an option, so a compile-time constant.
        self.contact_auto = contact_auto
        self.scaled_now = ti.field(ti.i32, ())
        # 1: the global step is Jacobi PCG this step (pcg; by_stiffness while the springs are stiff,
        # h^2 k_max / m_min > FACTOR_MAX_STIFFNESS). Set with A.
        self.by_stiffness = global_solver == "by_stiffness"  # a compile-time constant
        self.jacobi_now = ti.field(ti.i32, ())
        model.add_listener(self)

    def notify_model_changed(self, flags: int):
        """A stiffness, a damper coefficient or a mass changed: rebuild A at the next ``prepare``."""
        if flags & (CHANGED_SPRINGS | CHANGED_MASSES):
            self._matrix_dt = None

    def prepare(self, dt: float):
        """(Re)build A when dt changed or the model said a stiffness, a damper coefficient or a
        mass did (``notify_model_changed``); factorise it."""
        if float(dt) == self._matrix_dt:
            return
        self._k_weights(dt)
        if self.chol is not None:
            self._k_assemble()
            self.chol.factor()
            if not self.chol.ok[None]:
                raise FloatingPointError(
                    "fast_mass_spring: the matrix M + L is not positive definite (negative stiffness?)")
        self._matrix_dt = float(dt)
        self.factorizations += 1

    @ti.kernel
    def _k_weights(self, dt: float):
        m = self.model
        k_max = ti.cast(0.0, float)
        for g in range(m.n_groups):
            self.group_c[g] = dt * dt * m.group_k[g] + dt * m.group_kd[g]
            ti.atomic_max(k_max, m.group_k[g])
        m_min = ti.cast(1e30, float)
        for i in range(self.n):
            if self.model.free(i):
                ti.atomic_min(m_min, m.mass[i])
        beta = dt * dt * k_max / m_min
        scaled = 1
        if ti.static(self.contact_auto):
            scaled = ti.cast(beta <= SCALED_CONTACT_MAX_STIFFNESS, ti.i32)
        self.scaled_now[None] = scaled
        jacobi = ti.cast(beta > FACTOR_MAX_STIFFNESS, ti.i32)
        if ti.static(not self.by_stiffness):
            jacobi = 0 if ti.static(self.factorised) else 1
        self.jacobi_now[None] = jacobi
        for i in range(self.n):
            d = m.mass[i]
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                d += self.group_c[m.adj_group[e]]
            self.diag[i] = d if self.model.free(i) else 0.0

    @ti.kernel
    def _k_assemble(self):
        m = self.model
        self.chol.clear()
        for i in range(self.n):
            # Pinned rows become identity rows: their correction is zero (Dirichlet).
            self.chol.add(i, i, self.diag[i] if self.model.free(i) else 1.0)
        for s in range(m.n_springs):
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            if self.model.free(a) and self.model.free(b):
                self.chol.add(ti.max(a, b), ti.min(a, b), -self.group_c[m.spring_group[s]])
