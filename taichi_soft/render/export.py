"""Surface meshes per frame as PLY or OBJ files (``--export-mesh DIR``).

One file per frame, ``mesh_00000.ply`` ..., holding every body (merged): in PLY each vertex
carries a ``body`` index; in OBJ each body is its own object ``o body_<b>``. Positions in m,
unit vertex normals, triangles wound outward (counter-clockwise seen from outside).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .outputs import StagedDir

MESH_FORMATS = ("ply", "obj")


def write_ply(path: Path, vertices: np.ndarray, normals: np.ndarray, triangles: np.ndarray, body: np.ndarray,
              comment: str = ""):
    """Binary little-endian PLY: vertex x y z nx ny nz (float32) body (uint8); face index lists."""
    vert = np.empty(len(vertices), dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("body", "u1")])
    vert["p"], vert["n"], vert["body"] = vertices, normals, body
    face = np.empty(len(triangles), dtype=[("count", "u1"), ("idx", "<i4", 3)])
    face["count"], face["idx"] = 3, triangles
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header += [f"element vertex {len(vert)}", *(f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")),
               "property uchar body", f"element face {len(face)}", "property list uchar int vertex_indices",
               "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())


def write_obj(path: Path, vertices: np.ndarray, normals: np.ndarray, triangles: np.ndarray, body: np.ndarray,
              comment: str = ""):
    """Wavefront OBJ text: one object per body; faces ``f a//a b//b c//c`` (1-based, shared numbering)."""
    lines = [f"# {comment}"] if comment else []
    # Bodies occupy consecutive vertex ranges, so writing them body by body keeps the numbering.
    tri_body = body[triangles[:, 0]]
    for b in np.unique(body):
        lines.append(f"o body_{b}")
        sel = np.nonzero(body == b)[0]
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices[sel]]
        lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals[sel]]
        lines += [f"f {a}//{a} {b_}//{b_} {c}//{c}" for a, b_, c in triangles[tri_body == b] + 1]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


class MeshFrames:
    """Output sink: each frame's surface mesh into ``target`` as ``mesh_<frame>.<fmt>``."""

    def __init__(self, target: Path, fmt: str, surface):
        if fmt not in MESH_FORMATS:
            raise ValueError(f"mesh format {fmt!r}")
        self.fmt = fmt
        self.dir = StagedDir(target, "mesh", f".{fmt}")
        self.triangles = surface.triangles_np
        self.body = np.zeros(surface.n_vertices, dtype=np.uint8)
        for b, (first, count, _, _) in enumerate(surface.bodies):
            self.body[first:first + count] = min(b, 255)
        self._write = write_ply if fmt == "ply" else write_obj

    def add(self, mesh: tuple[np.ndarray, np.ndarray], index: int, time: float):
        """Write (vertices [n, 3] m, normals [n, 3]) of frame ``index`` at simulated ``time`` [s]."""
        vertices, normals = mesh
        self.dir.save(index, lambda path: self._write(path, vertices, normals, self.triangles, self.body,
                                                      comment=f"taichi-soft frame {index} t = {time:.6f} s"))

    def commit(self) -> Path:
        return self.dir.commit()

    def abort(self):
        self.dir.abort()
