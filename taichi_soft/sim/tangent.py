"""Tangent-linear (forward-mode) semi-implicit Euler in Taichi: a run and its derivatives with
respect to P parameters in one pass.

The state (x, v) [m, m/s] is stepped together with P tangents (dx/dp, dv/dp) [m, m/s per unit of
p], one per parameter, each the directional derivative of the step written out by hand: the spring
and damper force f = -(k (L - r) + kd (w . l)) l (d = x_a - x_b, L = |d|, l = d / (L + TINY),
w = v_a - v_b) and its derivative df = -(dc l + c dl), the contact acceleration (normal push
cancelled, Coulomb friction capped so it at most stops the tangential velocity) and the end-of-step
response (projection, restitution above the bounce threshold, impact friction), each branch chosen
by the real state as the engine chooses it. The real part is computed once per step and shared by
the P tangents, so a pass costs about one run plus a fraction of one per parameter.
``gradients.Problem`` (complex-step numpy, the same model) is the reference it is tested against.

Taichi's own forward mode (``ti.ad.FwdMode``) fails to compile these kernels in Taichi 1.7.4
(docs/gradients.md), hence the hand-written tangents. Fields are f64 whatever the run's
precision: a fit's Gauss-Newton steps need derivatives to many digits.

Memory per particle: x, v, the force sum, the inverse mass, 2 P tangents and P tangent force
sums (10 + 9 P f64); per spring: ends, rest length and group; the recorded frames are numpy arrays (3 (1 + P) reals
per particle and frame). Semi-implicit Euler only; one body on the plane, the tilted plane or no
terrain, without ``contact.impact_at_crossing`` (``gradients.Problem`` refuses the rest).
"""

import numpy as np
import taichi as ti

from .gradients import PARAMS, SPIN, TINY, VELOCITY, Problem
from .lattice import SPRING_KINDS
from .scalar_fields import assign
from .spring_codes import spring_group

F64 = ti.f64
VEC = ti.types.vector(3, F64)
# What a parameter changes, for the kernel's compile-time seeds: a group's stiffness or damping,
# one of the scalars, or the initial velocity or spin (these only start the tangent: dv(0) != 0).
K, KD, RESTITUTION, FRICTION, GRAVITY, MASS, START = range(7)


def _seed(name: str) -> tuple[int, int]:
    """(what the parameter changes, its spring group or -1) for a name of ``PARAMS``."""
    if name in VELOCITY + SPIN:
        return START, -1
    for kind_i, kind in enumerate(SPRING_KINDS):
        if name == f"k_{kind}":
            return K, spring_group(0, kind_i)
        if name == f"kd_{kind}":
            return KD, spring_group(0, kind_i)
    return {"restitution": RESTITUTION, "friction": FRICTION, "gravity": GRAVITY, "mass": MASS}[name], -1


@ti.data_oriented
class _Stepper:
    """The Taichi fields and the run kernel for one problem and one list of parameters (the seeds
    are compiled in; their values are fields)."""

    # Sign of the damper's term in the spring's derivative: -1 makes a wrong derivative on purpose,
    # so that the tests show their check catches one (read at compile time).
    damper_derivative_sign = 1.0

    def __init__(self, problem: Problem, params: tuple[str, ...]):
        self.params = params
        self.seeds = [_seed(p) for p in params]
        self.P = max(len(params), 1)
        n, s = len(problem.mass), len(problem.pairs)
        self.n, self.n_springs = n, s
        self.contact = bool(problem.contact)
        self.x, self.v, self.f = (ti.Vector.field(3, F64, n) for _ in range(3))
        self.dx, self.dv, self.df = (ti.Vector.field(3, F64, (n, self.P)) for _ in range(3))
        self.ends = ti.Vector.field(2, ti.i32, max(s, 1))
        self.rest = ti.field(F64, max(s, 1))
        self.group = ti.field(ti.i32, max(s, 1))
        self.group_k = ti.field(F64, len(problem.group_k))
        self.group_kd = ti.field(F64, len(problem.group_kd))
        self.inv_mass = ti.field(F64, n)
        self.gravity = ti.Vector.field(3, F64, ())
        self.gravity_dir = ti.Vector.field(3, F64, ())  # d gravity / d |gravity|
        self.point = ti.Vector.field(3, F64, ())
        self.normal = ti.Vector.field(3, F64, ())
        self.scalars = ti.field(F64, 5)  # restitution, friction, epsilon, bounce threshold, impact friction
        if s:
            self.ends.from_numpy(problem.pairs.astype(np.int32))
            self.rest.from_numpy(problem.rest.astype(np.float64))
            self.group.from_numpy(problem.group.astype(np.int32))

    def load(self, problem: Problem, coefficients: dict):
        """Copy the run's values (``TangentProblem._coefficients``) into the fields."""
        self.group_k.from_numpy(coefficients["group_k"])
        self.group_kd.from_numpy(coefficients["group_kd"])
        self.inv_mass.from_numpy(coefficients["inv_mass"])
        assign({self.gravity: coefficients["gravity"], self.gravity_dir: coefficients["gravity_dir"],
                self.point: problem.point if self.contact else np.zeros(3),
                self.normal: problem.normal if self.contact else np.array([0.0, 1.0, 0.0])})
        self.scalars.from_numpy(np.array([coefficients["restitution"], coefficients["friction"], problem.epsilon,
                                          problem.threshold, float(problem.impact_friction)]))
        self.x.from_numpy(problem.x0)
        self.v.from_numpy(coefficients["v0"])
        self.dx.fill(0.0)
        self.dv.from_numpy(self._start_tangents(problem))
        self.f.fill(0.0)
        self.df.fill(0.0)

    def _start_tangents(self, problem: Problem) -> np.ndarray:
        """dv/dp at the start [n, P, 3]: a unit vector for a velocity component, e x (x0 - centre)
        for a spin component, zero for the rest."""
        out = np.zeros((self.n, self.P, 3))
        for j, name in enumerate(self.params):
            if name in VELOCITY:
                out[:, j, VELOCITY.index(name)] = 1.0
            elif name in SPIN:
                out[:, j] = np.cross(np.eye(3)[SPIN.index(name)], problem.arm)
        return out

    # -- the kernel ------------------------------------------------------------------------------
    @ti.kernel
    def run(self, frame_steps: ti.types.ndarray(), out: ti.types.ndarray(), dout: ti.types.ndarray(),
            dt: F64, tangents: ti.template()):
        """Step to the last of ``frame_steps`` (increasing, from 0), writing x [frames, n, 3] to
        ``out`` and with ``tangents`` dx [frames, n, P, 3] to ``dout`` at each of them."""
        n_frames = frame_steps.shape[0]
        ti.loop_config(serialize=True)
        for _ in range(1):  # one serial task: the steps run in order on one thread
            frame = 0
            step = 0
            while frame < n_frames:
                if frame_steps[frame] == step:
                    self._record(out, dout, frame, tangents)
                    frame += 1
                else:
                    self._step(dt, tangents)
                    step += 1

    @ti.func
    def _record(self, out: ti.template(), dout: ti.template(), frame, tangents: ti.template()):
        for i in range(self.n):
            for c in ti.static(range(3)):
                out[frame, i, c] = self.x[i][c]
            if ti.static(tangents):
                for p in ti.static(range(self.P)):
                    for c in ti.static(range(3)):
                        dout[frame, i, p, c] = self.dx[i, p][c]

    @ti.func
    def _step(self, dt, tangents: ti.template()):
        for s in range(self.n_springs):
            self._spring(s, tangents)
        for i in range(self.n):
            self._particle(i, dt, tangents)

    @ti.func
    def _spring(self, s, tangents: ti.template()):
        """Spring s's force on its ends (end a gets f, end b -f), and with ``tangents`` its derivative."""
        a, b = self.ends[s][0], self.ends[s][1]
        g = self.group[s]
        k, kd, r = self.group_k[g], self.group_kd[g], self.rest[s]
        d = self.x[a] - self.x[b]
        length = d.norm()
        inv = 1.0 / (length + TINY)
        l = d * inv
        w = self.v[a] - self.v[b]
        wl = w.dot(l)
        c = k * (length - r) + kd * wl
        self.f[a] += -c * l
        self.f[b] -= -c * l
        if ti.static(tangents):
            inv_len = 0.0 if length == 0 else 1.0 / length
            for p in ti.static(range(self.P)):
                dd = self.dx[a, p] - self.dx[b, p]
                dw = self.dv[a, p] - self.dv[b, p]
                dlen = d.dot(dd) * inv_len
                dl = (dd - l * dlen) * inv
                dc = k * dlen + ti.static(self.damper_derivative_sign) * kd * (dw.dot(l) + w.dot(dl))
                kind, group = ti.static(self.seeds[p] if p < len(self.seeds) else (-1, -1))
                if ti.static(kind == K):
                    if g == group:
                        dc += length - r
                if ti.static(kind == KD):
                    if g == group:
                        dc += wl
                df = -(dc * l + c * dl)
                self.df[a, p] += df
                self.df[b, p] -= df

    @ti.func
    def _particle(self, i, dt, tangents: ti.template()):
        """Particle i's kick, contact acceleration, drift and contact response, and its tangents'."""
        im = self.inv_mass[i]
        free = ti.cast(im > 0, F64)
        f = self.f[i]
        a = self.gravity[None] * free + f * im
        x, v = self.x[i], self.v[i]
        # contact acceleration (Terrain.contact_accel): real branches, kept for the tangents
        n = self.normal[None]
        mu = self.scalars[1]
        an = 0.0
        pressed = False
        slide = False
        tn = 0.0
        mag = 0.0
        capped = False
        trial = ti.Vector.zero(F64, 3)
        if ti.static(self.contact):
            dist = n.dot(x - self.point[None])
            an = n.dot(a)
            if dist < self.scalars[2] and an < 0:
                pressed = True
                a -= an * n
                trial = v - n.dot(v) * n + dt * a
                tn = trial.norm()
                if tn > 0:
                    slide = True
                    cap = mu * (-an)
                    capped = cap < tn / dt
                    mag = cap if capped else tn / dt
                    a -= mag / tn * trial
        vn_ = v + dt * a
        xn = x + dt * vn_
        # response (Terrain.respond): projection, restitution above the threshold, impact friction
        dist1 = 0.0
        vnorm = 0.0
        hit = False
        bounce = 0.0
        kr = 0.0
        vt = vn_
        vt0 = vn_  # the tangential velocity before impact friction
        t = 0.0
        moving = False
        scale = 1.0
        positive = False
        vout = vn_
        if ti.static(self.contact):
            dist1 = n.dot(xn - self.point[None])
            if dist1 < 0:
                xn -= dist1 * n
            vnorm = n.dot(vn_)
            if dist1 < self.scalars[2] and vnorm < 0:
                hit = True
                bounce = ti.cast(-vnorm > self.scalars[3], F64)
                kr = self.scalars[0] * bounce
                vt = vn_ - vnorm * n
                vt0 = vt
                if self.scalars[4] != 0:
                    t = vt.norm()
                    if t > 0:
                        moving = True
                        scale = 1.0 - mu * (1.0 + kr) * (-vnorm) / t
                        positive = scale > 0
                        vt *= scale if positive else 0.0
                vout = vt - kr * vnorm * n
        self.x[i] = xn
        self.v[i] = vout
        self.f[i] = ti.Vector.zero(F64, 3)
        if ti.static(tangents):
            for p in ti.static(range(self.P)):
                kind, _g = ti.static(self.seeds[p] if p < len(self.seeds) else (-1, -1))
                da = self.df[i, p] * im
                if ti.static(kind == MASS):
                    da += f * (-im * im)
                if ti.static(kind == GRAVITY):
                    da += self.gravity_dir[None] * free
                dmu = ti.static(1.0 if kind == FRICTION else 0.0)
                dx, dv = self.dx[i, p], self.dv[i, p]
                if ti.static(self.contact):
                    if pressed:
                        dan = n.dot(da)
                        da -= dan * n
                        if slide:
                            dtrial = dv - n.dot(dv) * n + dt * da
                            dtn = trial.dot(dtrial) / tn
                            dmag = dtn / dt
                            if capped:
                                dmag = dmu * (-an) + mu * (-dan)
                            da -= ((dmag * tn - mag * dtn) / (tn * tn)) * trial + (mag / tn) * dtrial
                dvn = dv + dt * da
                dxn = dx + dt * dvn
                dvout = dvn
                if ti.static(self.contact):
                    if dist1 < 0:
                        dxn -= n.dot(dxn) * n
                    if hit:
                        dvnorm = n.dot(dvn)
                        dkr = bounce * ti.static(1.0 if kind == RESTITUTION else 0.0)
                        dvt = dvn - dvnorm * n
                        if moving:
                            dt_ = vt0.dot(dvt) / t
                            num = mu * (1.0 + kr) * (-vnorm)
                            dnum = dmu * (1.0 + kr) * (-vnorm) + mu * dkr * (-vnorm) + mu * (1.0 + kr) * (-dvnorm)
                            dscale = -(dnum * t - num * dt_) / (t * t)
                            if positive:
                                dvt = dvt * scale + vt0 * dscale
                            else:
                                dvt = ti.Vector.zero(F64, 3)
                        dvout = dvt - (dkr * vnorm + kr * dvnorm) * n
                self.dx[i, p] = dxn
                self.dv[i, p] = dvout
                self.df[i, p] = ti.Vector.zero(F64, 3)


class TangentProblem(Problem):
    """``gradients.Problem`` stepped by the Taichi tangent-linear kernel: the same ``values``,
    ``trajectory`` and ``jacobian``, with ``jacobian`` one pass for all its parameters."""

    def __init__(self, sim):
        super().__init__(sim)
        self._steppers: dict[tuple, _Stepper] = {}

    def _stepper(self, params: tuple[str, ...]) -> _Stepper:
        if params not in self._steppers:
            self._steppers[params] = _Stepper(self, params)
        return self._steppers[params]

    def _coefficients_for(self, values: dict) -> dict:
        """The run's parameter arrays (real) from ``values``, as ``gradients.Problem`` makes them."""
        gk, gkd, gravity, inv_mass, free, kr, mu, v0 = self._coefficients(values, None)
        gk_g = self.group_k.copy()
        gkd_g = self.group_kd.copy()
        for kind_i, kind in enumerate(SPRING_KINDS):
            g = spring_group(0, kind_i)
            gk_g[g] = values[f"k_{kind}"]
            gkd_g[g] = values[f"kd_{kind}"]
        g0 = float(np.linalg.norm(self.gravity))
        return {"group_k": gk_g, "group_kd": gkd_g, "inv_mass": np.asarray(inv_mass, dtype=np.float64),
                "gravity": np.asarray(gravity, dtype=np.float64),
                "gravity_dir": self.gravity / g0 if g0 > 0 else np.zeros(3), "restitution": float(kr),
                "friction": float(mu), "v0": np.asarray(v0, dtype=np.float64)}

    def passes(self, values: dict, frame_steps: list[int], params: list[str] | tuple = ()):
        """Positions [m], [frames, particles, 3], at ``frame_steps`` (step counts) and, for ``params``,
        their derivatives [m per unit of each parameter], [frames, particles, P, 3] (one pass; None
        without parameters)."""
        params = tuple(params)
        for p in params:
            if p not in PARAMS:
                raise ValueError(f"tangent: unknown parameter {p!r}")
        steps = np.asarray(frame_steps, dtype=np.int32)
        if len(steps) == 0 or steps[0] < 0 or np.any(np.diff(steps) <= 0):
            raise ValueError("tangent: frame steps must be increasing and not negative")
        st = self._stepper(params)
        st.load(self, self._coefficients_for(values))
        out = np.zeros((len(steps), st.n, 3))
        dout = np.zeros((len(steps), st.n, st.P, 3) if params else (1, 1, 1, 3))
        st.run(steps, out, dout, self.dt, bool(params))
        return out, (dout if params else None)

    def trajectory(self, values: dict, frame_steps: list[int], seed: str | None = None) -> np.ndarray:
        """Positions [m] at ``frame_steps`` [frames, particles, 3]; with ``seed`` their derivative
        with respect to that parameter instead (same shape)."""
        x, dx = self.passes(values, frame_steps, (seed,) if seed else ())
        return dx[:, :, 0] if seed else x

    def jacobian(self, values: dict, params: list[str], frame_steps: list[int]):
        """(positions [frames, particles, 3], {param: d positions / d param}): one pass for all."""
        x, dx = self.passes(values, frame_steps, params)
        return x, {p: dx[:, :, j] for j, p in enumerate(params)}
