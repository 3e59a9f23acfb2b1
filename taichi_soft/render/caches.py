"""Animation caches for Blender and Houdini: one USD stage (``--export-usd``) or Point Cache 2
files (``--export-pc2``), the bodies' surfaces sampled once per output frame.

Both are output sinks like ``export.MeshFrames`` (``add(mesh, index, time)``, ``commit()``,
``abort()``): everything is written beside its destination and renamed into place by
``commit()``, so a failed run leaves the old files or the complete new ones. The surface is
whatever the renderer draws: a cube's lattice boundary, a mesh body's input mesh embedded in its
lattice (``embedded.py``). Positions in metres, Y up, triangles wound counter-clockwise seen from
outside. docs/rendering.md says how to open them.
"""
from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..errors import OutputError, UserError
from ..outfiles import fsync_file, reserve_temp
from .export import write_obj
from .meshes import BODY_COLORS

USD_SUFFIXES = (".usd", ".usda", ".usdc")
PC2_HEADER = struct.Struct("<12siiffi")  # signature, version, points, start frame, sample rate, samples


def require_usd():
    """Import ``pxr`` (the ``usd-core`` package) or raise ``UserError`` saying how to get it."""
    try:
        from pxr import Usd, UsdGeom, Vt  # noqa: F401
    except ImportError:
        raise UserError("--export-usd needs the usd-core package: .venv/bin/python -m pip install usd-core") from None


def _body_ranges(surface):
    """[(first vertex, count, triangles [m, 3] local to the body)] per body of ``surface``."""
    out = []
    for first, count, first_index, index_count in surface.bodies:
        tris = surface.triangles_np.reshape(-1)[first_index:first_index + index_count].reshape(-1, 3) - first
        out.append((first, count, tris))
    return out


class UsdCache:
    """One USD stage: /World/body_<b> meshes with points, normals and extent sampled at each
    output frame (time code = frame number k, at ``fps`` codes per second: the video's frame k,
    the step nearest k / fps seconds), /World/terrain_<i> static meshes, Y up, 1 metre per unit."""

    def __init__(self, path: Path, surface, terrain_meshes, fps: float):
        require_usd()
        from pxr import Usd, UsdGeom, Vt

        self.path = Path(path)
        self.tmp = reserve_temp(self.path)
        self.fps = float(fps)
        self.stage = Usd.Stage.CreateNew(str(self.tmp))
        stage = self.stage
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        self.bodies = []
        for b, (first, count, tris) in enumerate(_body_ranges(surface)):
            mesh = UsdGeom.Mesh.Define(stage, f"/World/body_{b}")
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(tris)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(tris.ravel().tolist()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a triangle mesh, shaded smooth by normals
            mesh.CreateDisplayColorAttr([tuple(BODY_COLORS[b % len(BODY_COLORS)])])
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)  # one normal per point, sampled with them
            self.bodies.append((mesh, first, count))
        for i, t in enumerate(terrain_meshes):
            mesh = UsdGeom.Mesh.Define(stage, f"/World/terrain_{i}")
            mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(t.vertices, dtype=np.float32)))
            mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(t.normals, dtype=np.float32)))
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(t.triangles)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(np.asarray(t.triangles).ravel().tolist()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateDoubleSidedAttr(bool(t.two_sided))
            colors = mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
            colors.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(t.colors, dtype=np.float32)))
            mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(mesh.GetPointsAttr().Get()))
        self.last_code = None

    def add(self, mesh: tuple[np.ndarray, np.ndarray], index: int, time: float):
        from pxr import Vt

        vertices, normals = mesh
        code = float(index)  # frame k, as in the video: the step nearest k / fps seconds
        for usd_mesh, first, count in self.bodies:
            pts = np.ascontiguousarray(vertices[first:first + count], dtype=np.float32)
            nrm = np.ascontiguousarray(normals[first:first + count], dtype=np.float32)
            usd_mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts), code)
            usd_mesh.GetNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(nrm), code)
            usd_mesh.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(axis=0), pts.max(axis=0)])), code)
        if self.last_code is None:
            self.stage.SetStartTimeCode(code)
        self.last_code = code

    def commit(self) -> Path:
        if self.last_code is not None:
            self.stage.SetEndTimeCode(self.last_code)
        try:
            if not self.stage.GetRootLayer().Save():
                raise OutputError(f"USD {self.path} was not written: the stage could not be saved")
            self.stage = None
            fsync_file(self.tmp)
        except OSError as e:
            raise OutputError(f"USD {self.path} was not written: {e.strerror or e}") from None
        os.replace(self.tmp, self.path)
        return self.path

    def abort(self):
        self.stage = None
        self.tmp.unlink(missing_ok=True)


class Pc2Cache:
    """Per body ``body_<b>.pc2`` (Point Cache 2: a 32-byte header, then every frame's points as
    float32 x y z) and ``body_<b>.obj``, the first frame's surface with the same vertex order, for
    Blender's Mesh Cache modifier and Houdini. One sample per output frame, sample rate 1 frame,
    starting at frame 0."""

    def __init__(self, target: Path, surface):
        self.target = Path(target)
        self.target.mkdir(parents=True, exist_ok=True)
        self.bodies = _body_ranges(surface)
        self.files = []  # (destination, temporary, open file) of each body's .pc2
        self.objs = []  # (destination, temporary) of each body's rest-pose .obj
        self.samples = 0
        try:
            for b, (_, count, _) in enumerate(self.bodies):
                dest = self.target / f"body_{b}.pc2"
                tmp = reserve_temp(dest)
                f = open(tmp, "wb")
                f.write(PC2_HEADER.pack(b"POINTCACHE2\0", 1, count, 0.0, 1.0, 0))
                self.files.append((dest, tmp, f))
        except OSError as e:
            self.abort()
            raise OutputError(f"{self.target} was not written: {e.strerror or e}") from None

    def add(self, mesh: tuple[np.ndarray, np.ndarray], index: int, time: float):
        vertices, normals = mesh
        try:
            for b, ((first, count, tris), (dest, tmp, f)) in enumerate(zip(self.bodies, self.files)):
                pts = np.ascontiguousarray(vertices[first:first + count], dtype="<f4")
                f.write(pts.tobytes())
                if self.samples == 0:
                    obj = self.target / f"body_{b}.obj"
                    obj_tmp = reserve_temp(obj)
                    self.objs.append((obj, obj_tmp))
                    write_obj(obj_tmp, pts, normals[first:first + count], tris, np.full(count, b),
                              comment=f"taichi-soft body {b} rest pose for body_{b}.pc2 (frame 0, t = {time:.6f} s)")
        except OSError as e:
            raise OutputError(f"{self.target} was not written: {e.strerror or e}") from None
        self.samples += 1

    def commit(self) -> Path:
        try:
            for dest, tmp, f in self.files:
                f.seek(PC2_HEADER.size - 4)  # the header's sample count, unknown until now
                f.write(struct.pack("<i", self.samples))
                f.close()
                fsync_file(tmp)
            for _, tmp in self.objs:
                fsync_file(tmp)
        except OSError as e:
            raise OutputError(f"{self.target} was not written: {e.strerror or e}") from None
        for dest, tmp, _ in self.files:
            os.replace(tmp, dest)
        for dest, tmp in self.objs:
            os.replace(tmp, dest)
        self.files, self.objs = [], []
        return self.target

    def abort(self):
        for _, tmp, f in self.files:
            f.close()
            tmp.unlink(missing_ok=True)
        for _, tmp in self.objs:
            tmp.unlink(missing_ok=True)
        self.files, self.objs = [], []


def read_pc2(path: Path) -> np.ndarray:
    """The points of a Point Cache 2 file as float32 [samples, points, 3]."""
    data = Path(path).read_bytes()
    sig, version, points, _, _, samples = PC2_HEADER.unpack_from(data)
    if sig != b"POINTCACHE2\0" or version != 1:
        raise ValueError(f"{path}: not a Point Cache 2 file")
    return np.frombuffer(data, dtype="<f4", offset=PC2_HEADER.size).reshape(samples, points, 3)
