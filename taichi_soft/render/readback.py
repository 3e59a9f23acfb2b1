"""The kernel that turns GGUI's read-back into a video frame (``window.window_rgb`` calls it).

Kept apart from ``window`` because it imports Taichi at load time (and Taichi reads kernel
annotations as objects, which ``from __future__ import annotations`` would turn into strings).
"""
import taichi as ti


@ti.kernel
def float_image_to_rgb8(src: ti.types.ndarray(dtype=ti.f32, ndim=3), dst: ti.types.ndarray(dtype=ti.u8, ndim=3)):
    """``src``: GGUI's float32 [width, height, 4] image, values k / 255, origin bottom left;
    ``dst``: uint8 RGB [height, width, 3], top row first. One parallel pass: scale, round,
    transpose and flip."""
    height = dst.shape[0]
    for row in range(height):  # one output row per task: its bytes are written in order
        for col in range(dst.shape[1]):
            for c in ti.static(range(3)):
                # GGUI's values are exact k / 255 in [0, 1]: round, no clipping needed.
                dst[row, col, c] = ti.cast(src[col, height - 1 - row, c] * 255.0 + 0.5, ti.u8)
