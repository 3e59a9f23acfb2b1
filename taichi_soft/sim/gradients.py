"""Derivatives of a semi-implicit Euler run with respect to its parameters (forward mode).

Taichi's own forward mode (``ti.ad.FwdMode``) could not compile the engine's step kernels in
Taichi 1.7.4 (docs/gradients.md: the serial many-step kernel fails in ``auto_diff.cpp`` with
"Not supported", the parallel one with a ``MatrixPtrStmt`` assertion), so this module is the
reference stepper: semi-implicit Euler with springs, dampers, gravity and the plane's contact
model, written once in numpy over complex numbers (``tangent.py`` is the fast one that ``fit``
uses; its tests check it against this one). A parameter p is given an imaginary
part ``1j * H``; every operation is analytic in it (lengths are ``sqrt(d . d)``, branches and
min/max look at real parts), so Im(y) / H is dy/dp to rounding (complex-step differentiation:
no subtraction, hence no cancellation, the same as one forward-mode dual pass). One pass per
parameter, memory O(particles). ``tests/test_gradients.py`` checks that its real part equals the
engine's ``semi_implicit_euler`` and its derivatives against central finite differences.

Parameters (``PARAMS``): ``k_stretch``, ``k_shear``, ``k_bend`` [N/m], ``kd_stretch``,
``kd_shear``, ``kd_bend`` [N s/m] (of body 0), ``restitution`` [-], ``friction`` [-],
``gravity`` (its magnitude [m/s^2], direction kept), ``mass`` (every free particle's [kg]),
``velocity_x``, ``velocity_y``, ``velocity_z`` (the body's initial velocity [m/s]) and ``spin_x``,
``spin_y``, ``spin_z`` (its initial angular velocity [rad/s] about its centre).
"""
from __future__ import annotations

import numpy as np

from .lattice import SPRING_KINDS
from .spring_codes import spring_group

AXES = ("x", "y", "z")
VELOCITY = tuple(f"velocity_{a}" for a in AXES)
SPIN = tuple(f"spin_{a}" for a in AXES)
PARAMS = tuple([f"k_{k}" for k in SPRING_KINDS] + [f"kd_{k}" for k in SPRING_KINDS]
               + ["restitution", "friction", "gravity", "mass", *VELOCITY, *SPIN])
H = 1e-30  # the imaginary step: far below any parameter's rounding, so Re is the plain run
TINY = 1e-30  # forces.TINY: added to a spring's length before dividing by it


class Problem:
    """A one-body scene on a plane (or no terrain) as plain arrays: what ``trajectory`` steps.

    Built from a ``Simulation`` (its model and terrain fields, read once)."""

    def __init__(self, sim):
        m, t = sim.model, sim.terrain
        if len(m.bodies) != 1:
            raise ValueError("gradients: scenes with one body only")
        if t.kind not in ("plane", "tilted_plane", "none"):
            raise ValueError(f"gradients: terrain {t.kind!r} is not covered (plane, tilted_plane, none)")
        self.pairs = m.pairs_np.astype(np.int64)
        self.rest = m.rest_np
        self.group = m.group_np
        self.group_k = m.group_k.to_numpy()[: m.n_groups].astype(np.float64)
        self.group_kd = m.group_kd.to_numpy()[: m.n_groups].astype(np.float64)
        self.mass = m.mass_np.copy()
        self.x0, self.v0 = m.x0_np.copy(), m.v0_np.copy()
        # v0 = velocity + spin x (x0 - centre) (builder.py): kept as those two and what is left over
        spec = m.bodies[0].spec
        self.velocity = np.asarray(spec.velocity, dtype=np.float64)
        self.spin = np.asarray(spec.angular_velocity, dtype=np.float64)
        self.arm = self.x0 - np.asarray(spec.center, dtype=np.float64)
        self.v0_rest = self.v0 - (self.velocity + np.cross(self.spin, self.arm))
        self.gravity = np.asarray(m.gravity[None].to_numpy(), dtype=np.float64)
        self.contact = t.has_contact
        if self.contact:
            g = t.params()
            self.point, self.normal = np.asarray(g["point"]), np.asarray(g["normal"])
            self.restitution = float(t.restitution[None])
            self.friction = float(t.friction[None])
            self.epsilon = float(t.epsilon[None])
            self.threshold = float(t.bounce_threshold[None])
            self.impact_friction = bool(t.impact_friction[None])
            if int(t.impact_at_crossing[None]):
                raise ValueError("gradients: contact.impact_at_crossing is not covered")
        else:
            self.point = self.normal = None
            self.restitution = self.friction = self.epsilon = self.threshold = 0.0
            self.impact_friction = False
        self.dt = float(sim.dt)

    def values(self) -> dict:
        """The current value of every parameter of ``PARAMS``."""
        out = {}
        for kind_i, kind in enumerate(SPRING_KINDS):
            out[f"k_{kind}"] = float(self.group_k[spring_group(0, kind_i)])
            out[f"kd_{kind}"] = float(self.group_kd[spring_group(0, kind_i)])
        free = self.mass[self.mass > 0]
        out.update(restitution=self.restitution, friction=self.friction,
                   gravity=float(np.linalg.norm(self.gravity)), mass=float(free[0]) if len(free) else 0.0)
        out.update({name: float(c) for name, c in zip(VELOCITY, self.velocity)})
        out.update({name: float(c) for name, c in zip(SPIN, self.spin)})
        return out

    def _coefficients(self, values: dict, seed: str | None):
        """Parameter arrays (complex when ``seed`` names the parameter to differentiate)."""
        dtype = complex if seed else float
        bump = lambda name: values[name] + (1j * H if name == seed else 0.0)  # noqa: E731
        gk = self.group_k.astype(dtype)
        gkd = self.group_kd.astype(dtype)
        for kind_i, kind in enumerate(SPRING_KINDS):
            g = spring_group(0, kind_i)
            gk[g] = bump(f"k_{kind}")
            gkd[g] = bump(f"kd_{kind}")
        g0 = np.linalg.norm(self.gravity)
        gravity = self.gravity.astype(dtype) * (bump("gravity") / g0 if g0 > 0 else 1.0)
        free = self.mass > 0
        inv_mass = np.zeros(len(self.mass), dtype=dtype)
        inv_mass[free] = 1.0 / bump("mass")
        velocity = np.array([bump(name) for name in VELOCITY])
        spin = np.array([bump(name) for name in SPIN])
        v0 = self.v0_rest + velocity + np.cross(spin, self.arm)
        return (gk[self.group], gkd[self.group], gravity, inv_mass, free, bump("restitution"), bump("friction"),
                v0)

    def trajectory(self, values: dict, frame_steps: list[int], seed: str | None = None) -> np.ndarray:
        """Positions [m] at the given step counts, [frames, particles, 3]; with ``seed`` their
        derivative with respect to that parameter instead (same shape, [m per unit])."""
        k, kd, gravity, inv_mass, free, kr, mu, v0 = self._coefficients(values, seed)
        dtype = complex if seed else float
        x, v = self.x0.astype(dtype), v0.astype(dtype)
        a_end, b_end = self.pairs[:, 0], self.pairs[:, 1]
        dt = self.dt
        out = []
        wanted = list(frame_steps)
        step = 0
        while True:
            if wanted and wanted[0] == step:
                out.append(x.imag / H if seed else x.copy())
                wanted.pop(0)
            if not wanted:
                break
            d = x[a_end] - x[b_end]
            length = np.sqrt(np.sum(d * d, axis=1))
            ln = d * (1.0 / (length + TINY))[:, None]
            dv = v[a_end] - v[b_end]
            f = -(k * (length - self.rest) + kd * np.sum(dv * ln, axis=1))[:, None] * ln
            force = np.zeros_like(x)
            np.add.at(force, a_end, f)
            np.add.at(force, b_end, -f)
            acc = gravity[None, :] * free[:, None] + force * inv_mass[:, None]
            if self.contact:
                acc = self._contact_accel(x, v, acc, mu, dt)
            v = v + dt * acc
            x = x + dt * v
            if self.contact:
                x, v = self._respond(x, v, kr, mu)
            step += 1
        return np.stack(out)

    def _contact_accel(self, x, v, a, mu, dt):
        """``Terrain.contact_accel`` for every particle (branches on real parts)."""
        n = self.normal
        dist = (x - self.point) @ n
        an = a @ n
        pressed = (dist.real < self.epsilon) & (an.real < 0)
        a = np.where(pressed[:, None], a - an[:, None] * n, a)
        trial = v - (v @ n)[:, None] * n + dt * a
        tn = np.sqrt(np.sum(trial * trial, axis=1))
        slide = pressed & (tn.real > 0)
        safe = np.where(slide, tn, 1.0)
        cap = mu * (-an)
        mag = np.where(cap.real < (tn / dt).real, cap, tn / dt)
        return np.where(slide[:, None], a - (mag / safe)[:, None] * trial, a)

    def _respond(self, x, v, kr, mu):
        """``Terrain.respond``: projection, restitution above the threshold, impact friction."""
        n = self.normal
        dist = (x - self.point) @ n
        x = np.where((dist.real < 0)[:, None], x - dist[:, None] * n, x)
        vn = v @ n
        hit = (dist.real < self.epsilon) & (vn.real < 0)
        krs = kr * (-vn.real > self.threshold)
        vt = v - vn[:, None] * n
        if self.impact_friction:
            t = np.sqrt(np.sum(vt * vt, axis=1))
            moving = t.real > 0
            scale = 1.0 - mu * (1.0 + krs) * (-vn) / np.where(moving, t, 1.0)
            scale = np.where(scale.real > 0, scale, 0.0)
            vt = np.where(moving[:, None], vt * scale[:, None], vt)
        return x, np.where(hit[:, None], vt - (krs * vn)[:, None] * n, v)

    def jacobian(self, values: dict, params: list[str], frame_steps: list[int]):
        """(positions [frames, particles, 3], {param: d positions / d param}): one pass per parameter."""
        x = self.trajectory(values, frame_steps)
        return x, {p: self.trajectory(values, frame_steps, seed=p) for p in params}


BOUNDS = {"restitution": (0.0, 1.0), "friction": (0.0, np.inf),
          **{name: (-np.inf, np.inf) for name in VELOCITY + SPIN}}  # the others: > 0
POSITIVE_FLOOR = 1e-9  # a stiffness, damping, mass or gravity is kept at least this fraction of its start


def fit(problem: Problem, target: np.ndarray, frame_steps: list[int], params: list[str], start: dict | None = None,
        max_iters: int = 30, tol: float = 1e-12, progress=None, particles=None, step_tol: float = 1e-7,
        weights=None) -> dict:
    """Levenberg-Marquardt with bounds on ``params`` so that the positions at ``frame_steps``
    match ``target`` [frames, particles, 3] (with ``particles``, a list of particle indices, the
    target holds those particles only: marker tracks; with ``weights`` too, ``particles`` [markers, K]
    and ``weights`` [markers, K] make each marker a fixed combination of K particles, as
    ``rest_point_markers`` gives them: see ``observe``). It stops when the loss falls by less than
    ``tol`` of itself in an iteration, or no parameter moves by more than ``step_tol`` of its start
    (a kink of a contact's loss can hold it there for many tiny steps). Loss: mean over frames and particles of the squared
    distance [m^2]. Each iteration takes one Jacobian (``problem.jacobian``: one pass per parameter
    here, one pass for all of them with ``tangent.TangentProblem``) and one or more trial runs. Returns values, Gauss-Newton standard errors, loss history, counts.
    ``progress(iteration, loss, values)`` is called after each iteration."""
    values = dict(problem.values() if start is None else start)
    scale = {p: abs(values[p]) if values[p] != 0 else 1.0 for p in params}
    count = target[..., 0].size
    runs, grads = 0, 0
    def sel(x):
        return observe(x, particles, weights)

    def residual(vals):
        nonlocal runs
        runs += 1
        return ((sel(problem.trajectory(vals, frame_steps)) - target) / np.sqrt(count)).ravel()

    def clip(name, value):
        lo, hi = BOUNDS.get(name, (POSITIVE_FLOOR * scale[name], np.inf))
        return float(min(max(value, lo), hi))

    r = residual(values)
    loss = float(r @ r)
    history = [loss]
    lam = 1e-3
    jac = None
    for it in range(max_iters):
        x_and = problem.jacobian(values, params, frame_steps)
        grads += 1
        jac = np.stack([sel(x_and[1][p]).ravel() / np.sqrt(count) * scale[p] for p in params], axis=1)
        r = ((sel(x_and[0]) - target) / np.sqrt(count)).ravel()
        jtj, jtr = jac.T @ jac, jac.T @ r
        improved = False
        moved = 0.0
        for _ in range(12):
            step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-30), -jtr)
            trial = dict(values)
            for p, s in zip(params, step):
                trial[p] = clip(p, values[p] + s * scale[p])
            rt = residual(trial)
            lt = float(rt @ rt)
            if lt < loss:
                moved = max(abs(trial[p] - values[p]) / scale[p] for p in params)
                values, improved = trial, True
                lam = max(lam / 3, 1e-9)
                break
            lam *= 4
        history.append(min(loss, lt) if improved else loss)
        if progress is not None:
            progress(it + 1, history[-1], values)
        if (not improved or loss - history[-1] <= tol * max(loss, 1e-300) or history[-1] == 0.0
                or moved <= step_tol):
            loss = history[-1]
            break
        loss = history[-1]
    # Gauss-Newton uncertainty at the result: sigma^2 (J^T J)^-1, sigma^2 from the residual
    x_and = problem.jacobian(values, params, frame_steps)
    grads += 1
    jac = np.stack([sel(x_and[1][p]).ravel() / np.sqrt(count) for p in params], axis=1)
    r = ((sel(x_and[0]) - target) / np.sqrt(count)).ravel()
    dof = max(r.size - len(params), 1)
    sigma2 = float(r @ r) * count / dof
    try:
        cov = sigma2 / count * np.linalg.inv(jac.T @ jac)
        err = {p: float(np.sqrt(max(cov[i, i], 0.0))) for i, p in enumerate(params)}
    except np.linalg.LinAlgError:
        err = {p: None for p in params}
    return {"values": {p: values[p] for p in params}, "uncertainty": err, "loss_history": history,
            "loss": float(r @ r), "gradient_evaluations": grads, "forward_runs": runs,
            "gradient": {p: float(2 * (jac[:, i] @ r)) for i, p in enumerate(params)}}


def observe(x: np.ndarray, particles=None, weights=None) -> np.ndarray:
    """Marker positions [frames, markers, 3] from particle positions x [frames, particles, 3] [m]
    (or their derivatives with respect to a parameter: the map is linear, so the same combination
    of the particles' tangent columns is the markers' Jacobian). No ``particles``: every particle;
    ``particles`` a list of indices: those; with ``weights`` [markers, K], ``particles`` [markers, K]
    and marker m at sum_k weights[m, k] x[particles[m, k]]."""
    if particles is None:
        return x
    idx = np.asarray(particles, dtype=np.int64)
    if weights is None:
        return x[:, idx]
    return np.einsum("fmkc,mk->fmc", x[:, idx], np.asarray(weights, dtype=np.float64))


SNAP = 1e-9  # lattice coordinates [cells] this close to a whole number are taken as on the lattice plane


def rest_point_markers(spec, points, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Markers on a cube body given by points on its rest shape: (particles [M, 8], weights [M, 8]),
    each marker the trilinear interpolation of the 8 lattice particles of the cell holding it.

    ``points`` [M, 3] [m] are in the scene's world frame on the body's rest shape as the scene
    places it at t = 0: the lattice of edge ``spec.size`` without ``initial_stretch``, turned by the
    body's rotation and centred on ``spec.center`` (rest = center + R p, p in [-size/2, size/2]^3
    in the body's frame). A point within 1e-9 of a cell of a lattice plane is put on it, so a point
    on a particle is that particle alone (weight 1). ``first``: the body's first particle index.
    ``ValueError`` (one line) for a point outside the lattice or a body that is not a cube."""
    from .lattice import rotation_matrix

    if spec.shape != "cube":
        raise ValueError(f"rest-point markers cover cube bodies; this body is a {spec.shape!r} "
                         "(give particle indices)")
    n, size = int(spec.n), float(spec.size)
    if n < 2:
        raise ValueError("rest-point markers need a lattice of at least 2 points per side")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rot = rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
    local = (points - np.asarray(spec.center, dtype=np.float64)) @ rot  # R^T (r - c), row-wise
    u = (local + 0.5 * size) / (size / (n - 1))  # lattice coordinates [cells]
    near = np.rint(u)
    u = np.where(np.abs(u - near) <= SNAP, near, u)
    outside = np.any((u < 0) | (u > n - 1), axis=1)
    if outside.any():
        m = int(np.argmax(outside))
        shown = ", ".join(f"{c:g}" for c in points[m])
        body = ", ".join(f"{c:g}" for c in local[m])
        raise ValueError(f"rest point ({shown}) m is outside the body's rest shape (at ({body}) m in the "
                         f"body's frame, whose lattice spans -{size / 2:g} to {size / 2:g} m on each axis)")
    base = np.minimum(np.floor(u), n - 2).astype(np.int64)
    f = u - base
    particles = np.empty((len(points), 8), dtype=np.int64)
    weights = np.empty((len(points), 8))
    for c, (a, b, e) in enumerate(np.ndindex(2, 2, 2)):
        corner = base + np.array([a, b, e])
        particles[:, c] = first + (corner[:, 0] * n + corner[:, 1]) * n + corner[:, 2]
        weights[:, c] = np.prod(np.where(np.array([a, b, e], dtype=bool), f, 1.0 - f), axis=1)
    return particles, weights
