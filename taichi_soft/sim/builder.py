"""Building a model: ``ModelBuilder`` collects bodies on the numpy side; ``finalize()`` makes a
``Model`` of Taichi fields, writing the lattice springs on the device (no host copies of the
per-spring arrays) and uploading a mesh body's springs from its (cached) ``MeshLattice``.
"""

import numpy as np
import taichi as ti

from . import lattice, meshbody
from .bodies import BodyInfo, BodySpec
from .model import Model
from .spring_codes import N_KINDS, spring_group


class ModelBuilder:
    """Collects bodies on the host; ``finalize()`` makes the device ``Model``."""

    def __init__(self, gravity=(0.0, -9.8, 0.0)):
        self.gravity = tuple(float(g) for g in gravity)
        self.specs: list[BodySpec] = []

    def add_cube(self, spec: BodySpec) -> int:
        """Add a soft body (a cube, or a mesh body when ``spec.shape == "mesh"``); returns its index."""
        self.specs.append(spec)
        return len(self.specs) - 1

    def finalize(self, springs: bool = True) -> "Model":
        """The device ``Model``. Host memory: x0, v0 and masses (56 bytes per particle) kept,
        one body's lattice (24 bytes per particle) as a temporary; a cube's springs are made on
        the device, a mesh body's uploaded from its (cached) ``MeshLattice``."""
        meshes = [meshbody.spec_lattice(spec, f"body.{b}.mesh") if spec.shape == "mesh" else None
                  for b, spec in enumerate(self.specs)]
        n_particles = sum(m.n_particles if m else spec.n ** 3 for spec, m in zip(self.specs, meshes))
        x0 = np.empty((n_particles, 3))
        v0 = np.empty((n_particles, 3))
        mass = np.empty(n_particles)
        bodies, group_k, group_kd, kind_counts = [], [], [], np.zeros(N_KINDS, np.int64)
        p0 = s0 = 0
        for spec, mesh in zip(self.specs, meshes):
            rot = lattice.rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
            pts = mesh.points.copy() if mesh else lattice.lattice_points(spec.n, spec.size)
            pts *= np.asarray(spec.initial_stretch, dtype=np.float64)
            sl = slice(p0, p0 + len(pts))
            x, v = x0[sl], v0[sl]
            np.matmul(pts, rot.T, out=x)  # start shape about the centre
            del pts
            w = np.asarray(spec.angular_velocity, dtype=np.float64)
            # v = velocity + omega x r, written as r @ K^T with K the cross-product matrix of omega
            cross = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
            np.matmul(x, cross.T, out=v)
            v += np.asarray(spec.velocity, dtype=np.float64)
            x += np.asarray(spec.center, dtype=np.float64)
            mass[sl] = spec.particle_mass
            for k, kd in (spec.stretch, spec.shear, spec.bend):
                group_k.append(k)
                group_kd.append(kd)
            counts = mesh.spring_counts() if mesh else lattice.spring_counts(spec.n)
            kind_counts += counts
            surf = (meshbody.particle_surface(mesh) if mesh else lattice.surface_triangles(spec.n)) + p0
            bodies.append(BodyInfo(sl, slice(s0, s0 + sum(counts)), surf, spec, mesh))
            p0 += len(x)
            s0 += sum(counts)
        model = Model.__new__(Model)
        model._setup(x0, v0, mass, s0, kind_counts, group_k, group_kd, self.gravity, bodies, springs)
        model._lattice = all(m is None for m in meshes)  # slab ranges by lattice arithmetic only for whole cubes
        model._spring_filler = _fill_model_springs  # run by model.ensure_springs
        if springs:
            model.ensure_springs()
        return model


def _fill_model_springs(model):
    """Write every body's springs into the model's spring fields (``Model.ensure_springs``)."""
    for b, info in enumerate(model.bodies):
        spec = info.spec
        if info.mesh is not None:
            if info.mesh.n_springs:
                m = info.mesh
                _put_springs(model.spring_ends, model.spring_rest, model.spring_group, m.pairs,
                             m.rest.astype(model.real), m.kind.astype(np.int32), info.particles.start,
                             info.springs.start, spring_group(b, 0))
            continue
        lattice.fill_springs(model.spring_ends, model.spring_rest, model.spring_group, spec.n,
                             info.particles.start, info.springs.start, spring_group(b, 0),
                             spec.size / (spec.n - 1))


@ti.kernel
def _put_springs(ends: ti.template(), rest: ti.template(), group: ti.template(), pairs: ti.types.ndarray(ndim=2),
                 length: ti.types.ndarray(ndim=1), kind: ti.types.ndarray(ndim=1), p0: ti.i32, s0: ti.i32, g0: ti.i32):
    """Write one body's springs given as host arrays (local particle indices) at ids s0, s0 + 1, ..."""
    for s in range(pairs.shape[0]):
        ends[s0 + s] = ti.Vector([p0 + pairs[s, 0], p0 + pairs[s, 1]])
        rest[s0 + s] = ti.cast(length[s], float)
        group[s0 + s] = g0 + kind[s]
