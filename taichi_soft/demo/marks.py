"""Markers drawn over the body: pinned particles in their own colour, the grabbed particle and
the point it is pulled toward."""

import numpy as np
import taichi as ti

PIN_COLOR = (0.85, 0.10, 0.10)  # red
GRAB_COLOR = (1.0, 0.85, 0.10)  # yellow: the grabbed particle
TARGET_COLOR = (0.20, 0.90, 1.0)  # cyan: where the hand pulls it
MAX_MARKS = 512  # pins drawn at most (more are kept, not drawn)


@ti.data_oriented
class Marks:
    """Positions [m] and colours of the markers, gathered on the device each frame."""

    def __init__(self):
        self.index = ti.field(ti.i32, MAX_MARKS)  # particle of each marker, -1: the grab target
        self.points = ti.Vector.field(3, ti.f32, MAX_MARKS)
        self.colors = ti.Vector.field(3, ti.f32, MAX_MARKS)
        self.count = 0
        self._key = None

    @ti.kernel
    def _gather(self, x: ti.template(), target: ti.template(), count: ti.i32):
        for k in range(count):
            i = self.index[k]
            if i >= 0:
                self.points[k] = ti.cast(x[i], ti.f32)
            else:
                self.points[k] = ti.cast(target[None], ti.f32)

    def update(self, ctl):
        """Gather this frame's markers from the controller's pins and grab."""
        held = ctl.grab.held
        key = (tuple(sorted(ctl.pins))[:MAX_MARKS - 2], held)
        if key != self._key:  # upload indices and colours only when they change
            pins, _ = key
            index = list(pins) + ([held, -1] if held is not None else [])
            colors = [PIN_COLOR] * len(pins) + ([GRAB_COLOR, TARGET_COLOR] if held is not None else [])
            self.count = len(index)
            if self.count:
                idx = np.full(MAX_MARKS, -1, np.int32)
                idx[: self.count] = index
                col = np.zeros((MAX_MARKS, 3), np.float32)
                col[: self.count] = colors
                self.index.from_numpy(idx)
                self.colors.from_numpy(col)
            self._key = key
        if self.count:
            self._gather(ctl.sim.state.x, ctl.grab.target, self.count)

    def draw(self, scene, radius: float):
        if self.count:
            scene.particles(self.points, radius=radius, per_vertex_color=self.colors, index_count=self.count)
