"""Restitution carried by the springs: the bounce as an implicit velocity step of the whole body.

``TerrainContact.bounce`` (contact.py) asks every held particle that hit the terrain faster than the
``bounce_threshold`` for a normal velocity change dv_N (to ``restitution`` times its approach
speed). Given to those particles alone, after the solve, a stiff body lost it: the held layer
had stopped the whole body, the bottom layer alone bounced, and the next steps' springs spread its
momentum over the body while backward Euler damped the compression wave that, at small explicit
steps, rebounds the body. A cube dropped flat at stiffness x1000 rose to 1.19 m instead of 5.36 m
at every step from 1/30 s to 1/480 s (issue 22).

Here the bounce is a velocity target of the held particles in a backward-Euler velocity step of
the whole body over the step h:

    (M + h^2 K + h D + F) dv = P,   dv . N_i = dv_N,i on every held particle,

(K the spring Hessian, D the dampers, F the friction blocks: the solver's own operator at the
end of the step, ``apply``; P the terrain's impulse on the held particles, the unknowns the free
components). Bouncing particles get exactly their restitution velocity; held particles that do
not bounce keep a zero normal change; every other velocity follows through the springs. The
response reaches about h sqrt(k/m) lattice spacings: in a soft body or at a small step it stays
at the held particles, as before; in a stiff body at a frame step it moves the body as a whole,
as the impact wave would. The solve is the solver's PCG on the filtered system, run only on steps
with a bounce (walk.py). The tangential friction loss of a bounce (``impact_friction``) stays local.

The driver then scales the whole dv by one factor s in [0, 1], the largest for which the kinetic
energy it adds fits in the energy the step lost (``StepEnd._bounce_scale``, step_end.py):
restitution never adds energy the step did not have.

Tried and not kept (issue 22): Poisson's hypothesis, an impulse e times the multiplier the held
particle took in the step, given to the body through the same operator with the bouncing
particles free. Backward Euler's velocity of a held particle is (x_{n+1} - x_n)/h, so the
multiplier misses the momentum the step's end velocity still carries: a 4^3 cube at x1000 and
1/120 s left at 3.0 m/s instead of 6.4 m/s.
"""

import taichi as ti

from ...footprint import VEC, per_particle


BOUNCE_CG_TOL = 1e-3  # relative PCG residual of the restitution solve (it runs on bounce steps only)


@ti.data_oriented
class SpreadBounce:
    """Mixin of ``ImplicitIntegrator``: restitution as a velocity step through the body."""

    BUFFERS = {
        "bounce_n": per_particle("prescribed normal velocity change dv_N N [m/s]", VEC),
        "bounce_rhs": per_particle("-(A dv_N N), filtered [kg m/s]", VEC),
        "bounce_dv": per_particle("response of the free components [m/s]", VEC),
    }

    @ti.func
    def _bounce_split(self, i, delta):
        """Record the normal part of held particle i's restitution ``delta`` [m/s] as prescribed;
        returns the part that stays local (the tangential friction loss)."""
        dn = ti.Vector.zero(float, 3)
        if ti.static(self.terrain.has_contact):
            if self.contact.active[i]:
                nrm = self.contact.normal[i]
                dn = nrm.dot(delta) * nrm
                if dn.norm_sqr() > 0:
                    self.sc.n_bounce[None] += 1.0
        self.bounce_n[i] = dn
        return delta - dn

    @ti.func
    def _bounce_rhs(self):
        """rhs = -A (dv_N N), filtered: the free components' share of the prescribed change."""
        self.apply(self.bounce_n, self.bounce_rhs)
        for i in range(self.n):
            self.bounce_rhs[i] = -self.bounce_rhs[i]
        self.pcg.rel_tol[None] = BOUNCE_CG_TOL

    @ti.func
    def _bounce_total(self, i):
        """Particle i's whole restitution velocity change [m/s] (after the spread: walk.py)."""
        dv = self.dv[i] + self.bounce_n[i]
        if self.sc.n_bounce[None] > 0:
            dv += self.bounce_dv[i]
        return dv
