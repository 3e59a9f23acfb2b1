"""The real surface of mesh bodies: the input triangle mesh embedded in the particle lattice.

A mesh body (``shape = "mesh"``, ``meshbody.py``) is simulated as a lattice of particles; what
it looks like is the mesh it was made from. Each vertex of that mesh is a fixed weighted sum of
particles (trilinear weights of its lattice cell, or affine weights over the particles nearest
its cell in boundary cells that miss corners: ``meshbody.MeshLattice.embed_*``), so the surface follows
the lattice as it bends, squashes and rotates.

``EmbeddedSurface`` has the interface of ``meshes.SurfaceMesh`` (vertices, normals, indices,
triangles_np, bodies, vertex_body, ``update(x)``, ``numpy()``): the renderer, the mesh exporters
and the animation caches take either. Cubes in the same model are surfaces whose vertices each
follow one particle with weight 1. ``body_surface(model)`` picks the plain ``SurfaceMesh`` when
no body is a mesh body.
"""
import numpy as np
import taichi as ti

from .meshes import SurfaceMesh, smooth_normals


def body_surface(model):
    """The device surface of every body of ``model``: ``SurfaceMesh`` for cubes only, else
    ``EmbeddedSurface``."""
    if all(body.mesh is None for body in model.bodies):
        return SurfaceMesh(model)
    return EmbeddedSurface(model)


def _pad(a: np.ndarray, width: int) -> np.ndarray:
    """Rows of ``a`` [n, w] padded with zeros to ``width`` columns."""
    return np.pad(a, ((0, 0), (0, width - a.shape[1])))


@ti.data_oriented
class EmbeddedSurface:
    """Every body's surface on the device, in f32, each vertex a weighted sum of particles.

    Fields: ``vertices``, ``normals`` [n_vertices] vec3 (m, unit); ``indices`` [3 n_triangles];
    ``follow`` [n_vertices, width] particle indices and ``weight`` [n_vertices, width] their
    weights (rows padded with weight 0). ``bodies[b]`` = (first vertex, vertex count, first index,
    index count) of body b; ``vertex_body`` [n_vertices] the body of each vertex.
    """

    def __init__(self, model):
        follow, weight, triangles, body_of, self.bodies = [], [], [], [], []
        nv = ni = 0
        for b, body in enumerate(model.bodies):
            p0 = body.particles.start
            if body.mesh is not None:
                m = body.mesh
                idx, w, tris = m.embed_index + p0, m.embed_weight, m.triangles
            else:
                used, local = np.unique(body.surface, return_inverse=True)
                idx, w, tris = used[:, None], np.ones((len(used), 1)), local.reshape(-1, 3)
            follow.append(idx)
            weight.append(w)
            triangles.append(tris + nv)
            self.bodies.append((nv, len(idx), ni, tris.size))
            body_of.append(np.full(len(idx), b, np.int32))
            nv += len(idx)
            ni += tris.size
        width = max(a.shape[1] for a in follow)
        self.width = width
        self.n_vertices, self.n_triangles = nv, ni // 3
        self.triangles_np = np.concatenate(triangles).astype(np.int32)
        self.vertex_body = np.concatenate(body_of)
        self.follow = ti.field(ti.i32, (nv, width))
        self.weight = ti.field(ti.f32, (nv, width))
        self.follow.from_numpy(np.concatenate([_pad(a, width) for a in follow]).astype(np.int32))
        self.weight.from_numpy(np.concatenate([_pad(a, width) for a in weight]).astype(np.float32))
        self.vertices = ti.Vector.field(3, ti.f32, nv)
        self.normals = ti.Vector.field(3, ti.f32, nv)
        self.indices = ti.field(ti.i32, 3 * self.n_triangles)
        self.indices.from_numpy(self.triangles_np.ravel())

    @ti.kernel
    def update(self, x: ti.template()):
        """Place every vertex from the particle positions ``x`` and recompute its normal
        (``meshes.smooth_normals``, as ``SurfaceMesh.update``)."""
        for v in range(self.n_vertices):
            p = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
            for c in range(self.width):
                p += self.weight[v, c] * ti.cast(x[self.follow[v, c]], ti.f32)
            self.vertices[v] = p
            self.normals[v] = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
        smooth_normals(self.vertices, self.normals, self.indices)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices [n_vertices, 3] m, normals [n_vertices, 3]) as float32 copies."""
        return self.vertices.to_numpy(), self.normals.to_numpy()

    def positions(self, x: np.ndarray) -> np.ndarray:
        """Vertex positions [n_vertices, 3] from particle positions ``x`` [n_particles, 3] on the
        host, in float64 (what ``update`` computes on the device in f32)."""
        follow, weight = self.follow.to_numpy(), self.weight.to_numpy().astype(np.float64)
        return np.einsum("vc,vcd->vd", weight, np.asarray(x, dtype=np.float64)[follow])
