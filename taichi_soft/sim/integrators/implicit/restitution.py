"""Restitution carried by the springs: the bounce as an implicit velocity step of the whole body.

``TerrainContact.bounce`` (contact.py) asks every held particle that hit the terrain faster than the
``bounce_threshold`` for a normal velocity change dv_N (to ``restitution`` times its approach
speed). Given to those particles alone, after the solve, a stiff body lost it: the held layer
had stopped the whole body, the bottom layer alone bounced, and the next steps' springs spread its
momentum over the body while backward Euler damped the compression wave that, at small explicit
steps, rebounds the body. A cube dropped flat at stiffness x1000 rose to 1.19 m instead of 5.36 m
at every step from 1/30 s to 1/480 s.

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

Tried and not kept: Poisson's hypothesis, an impulse e times the multiplier the held
particle took in the step, given to the body through the same operator with the bouncing
particles free. Backward Euler's velocity of a held particle is (x_{n+1} - x_n)/h, so the
multiplier misses the momentum the step's end velocity still carries: a 4^3 cube at x1000 and
1/120 s left at 3.0 m/s instead of 6.4 m/s.
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import VEC, per_particle


BOUNCE_CG_TOL = 1e-3  # relative PCG residual of the restitution solve (it runs on bounce steps only)


@ti.data_oriented
class BounceSpread:
    """Restitution as a velocity step through the body: a part of ``ImplicitIntegrator``.

    Inputs, given at construction: the particle count, the terrain contact part (``contact``:
    which particles are held, their normals) and the step's scalars ``sc`` (it counts
    ``n_bounce``); per call, the restitution a particle asks for and the linear operator (the
    solver: ``apply``). Outputs: ``rhs`` (the system the driver solves by PCG into ``response``) and
    each particle's whole velocity change (``total``).
    """

    BUFFERS = {
        "prescribed": per_particle("prescribed normal velocity change dv_N N [m/s]", VEC),
        "rhs": per_particle("-(A dv_N N), filtered [kg m/s]", VEC),
        "response": per_particle("response of the free components [m/s]", VEC),
    }

    def __init__(self, n: int, contact, sc):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open)."""
        self.n = n
        self.contact = contact
        self.sc = sc
        allocate(self, self.BUFFERS, n, 0)

    @ti.func
    def split(self, i, delta):
        """Record the normal part of held particle i's restitution ``delta`` [m/s] as prescribed;
        returns the part that stays local (the tangential friction loss)."""
        dn = ti.Vector.zero(float, 3)
        if self.contact.active[i]:
            nrm = self.contact.normal[i]
            dn = nrm.dot(delta) * nrm
            if dn.norm_sqr() > 0:
                self.sc.n_bounce[None] += 1.0
        self.prescribed[i] = dn
        return delta - dn

    @ti.func
    def set_rhs(self, op: ti.template()):
        """rhs = -A (dv_N N), filtered (A: ``op.apply``): the free components' share of the
        prescribed change."""
        op.apply(self.prescribed, self.rhs)
        for i in range(self.n):
            self.rhs[i] = -self.rhs[i]

    @ti.func
    def total(self, i, local):
        """Particle i's whole restitution velocity change [m/s] (after the spread, walk.py): its
        ``local`` part, the prescribed normal change and the response through the body."""
        dv = local + self.prescribed[i]
        if self.sc.n_bounce[None] > 0:
            dv += self.response[i]
        return dv
