"""An offscreen triangle rasterizer in Taichi kernels: the CPU path to a frame in a few ms.

On a machine without a GPU, GGUI draws through Mesa's lavapipe, whose fixed cost per frame
(an unlit ground quad at 1280 x 720: ~40 ms) is above the whole frame budget. This module draws
the same triangles with the same per-vertex lit colours (``lighting.shade``) on every core, in
two passes over one 64-bit field:

1. ``_raster``, one task per triangle: project its corners with GGUI's view and projection
   matrices (``camera.py``), find on each row of its screen bounding box the span of pixels it
   covers, interpolate the corners' colours there with perspective-correct barycentric weights
   (Gouraud shading, as GGUI draws per-vertex lit colours) and keep, per pixel, the smallest key
   ``(depth bits << 32) | RGB`` with an atomic min. The key is the depth test, the colour and
   the tie-break in one: the image does not depend on thread order.
2. ``_resolve``, one task per row: unpack the colours (background where nothing was drawn),
   uint8 RGB, top row first, and reset the keys for the next frame. Given a shadow map
   (``shadows.ShadowPass``, drawn by this same class from the key light) it darkens the pixels
   the map hides by the key light's share of their colour, kept in the key's bits 24-31; given
   the bodies drawn apart at ``factor`` x ``factor`` samples a pixel (``shadows.BodyPass``) it
   composites and averages them over this image (the terrain), which may be kept across frames.

Triangles are set up in homogeneous coordinates (Olano and Greer, "Triangle scan conversion
using 2D homogeneous coordinates", 1997): with the corners' (x_pixel w, y_pixel w, w) as the
columns of M, pixel (px, py) sees the triangle point with barycentric weights b / sum(b),
b = M^-1 (px, py, 1), at view depth w = 1 / sum(b); all b >= 0 means the point is inside and in
front. No triangle is clipped against the near plane: points behind the camera get negative
weights. Depth is view-space w in f32 (relative precision 6e-8); pixels outside
[Z_NEAR, Z_FAR] are dropped, as GGUI's clip volume does. Pixels are sampled at their centres,
as Vulkan does; a pixel exactly on an edge shared by two triangles goes to the nearer one,
then to the smaller colour key (deterministic; Vulkan's top-left rule gives it to one of the
two, so edge pixels may differ from GGUI's, by the colour step across that edge).

Only triangle meshes are drawn (no lines, no particle spheres: those need GGUI).
"""
import numpy as np
import taichi as ti

from .camera import Z_FAR, Z_NEAR, projection_matrix, view_matrix

EMPTY = (1 << 63) - 1  # key of a pixel that no triangle covers
mat4f = ti.types.matrix(4, 4, ti.f32)
mat34f = ti.types.matrix(3, 4, ti.f32)
vec2f = ti.types.vector(2, ti.f32)
vec3f = ti.types.vector(3, ti.f32)
ivec4 = ti.types.vector(4, ti.i32)
SHARE_SHIFT = 24  # bits 24-31 of a key: the key light's share of the colour, 0-255
TERMINATOR = 0.2  # cosine between a body triangle and the key light below which its shadow fades


@ti.func
def _unpack(key):
    """RGB 0-255 (f32) and the key light's share (0-1) of a drawn pixel's key."""
    rgb = ti.Vector([ti.f32((key >> 16) & 255), ti.f32((key >> 8) & 255), ti.f32(key & 255)])
    return rgb, ti.f32((key >> SHARE_SHIFT) & 255) / 255.0


@ti.func
def _depth(key):
    return ti.bit_cast(ti.cast(key >> 32, ti.i32), ti.f32)


@ti.func
def _lit(smap, light, bias, px, py, w):
    """Fraction of the key light reaching the surface point seen at pixel coordinates (px, py)
    [px] at view depth ``w`` [m]: 2 x 2 bilinear percentage-closer filtering of the shadow map
    ``smap`` (keys of the casters' far sides, seen from the light), ``light`` mapping
    (px w, py w, w, 1) to the map's homogeneous pixel coordinates."""
    h = light @ ti.Vector([px * w, py * w, w, 1.0], dt=ti.f32)
    lit = 1.0
    if h[2] > 0.0:
        size_y, size_x = smap.shape
        fx, fy = h[0] / h[2] - 0.5, h[1] / h[2] - 0.5
        x0, y0 = ti.floor(fx), ti.floor(fy)
        tx, ty = fx - x0, fy - y0
        ix, iy = ti.cast(x0, ti.i32), ti.cast(y0, ti.i32)
        if ix >= -1 and iy >= -1 and ix < size_x and iy < size_y:
            lit = 0.0
            for k in ti.static(range(4)):
                cx, cy = ix + k % 2, iy + k // 2
                weight = (tx if k % 2 else 1.0 - tx) * (ty if k // 2 else 1.0 - ty)
                hidden = False
                if 0 <= cx < size_x and 0 <= cy < size_y:
                    key = smap[cy, cx]
                    hidden = key != ti.i64(EMPTY) and _depth(key) < h[2] - bias
                if not hidden:
                    lit += weight
    return lit


@ti.func
def _corner(verts, mvp, pixel_scale, v):
    """Homogeneous pixel coordinates (x w, y w, w) of vertex ``v``: row 0 at the top."""
    c = mvp @ ti.Vector([verts[v][0], verts[v][1], verts[v][2], 1.0], dt=ti.f32)
    return ti.Vector([(c[0] + c[3]) * 0.5 * pixel_scale[0], (c[3] - c[1]) * 0.5 * pixel_scale[1], c[3]], dt=ti.f32)


@ti.data_oriented
class TaichiRasterizer:
    """Renders triangle meshes into ``width`` x ``height`` uint8 RGB images with a depth buffer.

    Per frame: ``begin(cam, background)``, ``draw(vertices, indices, colors, cull)`` per mesh,
    then ``finish()`` returns the image [height, width, 3] (row 0 at the top).
    """

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)
        self.key = ti.field(ti.i64, (self.height, self.width))
        self.key.from_numpy(np.full((self.height, self.width), EMPTY, np.int64))
        self._mvp = None
        self._background = (0.0, 0.0, 0.0)

    def begin(self, cam, background):
        """Start a frame seen by ``cam`` (a ``CameraSpec``) over ``background`` (RGB in [0, 1])."""
        self._mvp = (projection_matrix(cam, self.width / self.height) @ view_matrix(cam)).astype(np.float32)
        self._background = tuple(float(c) for c in background)

    def begin_matrix(self, mvp, background):
        """Start a frame through the 4 x 4 world -> clip matrix ``mvp`` (a part of a larger image:
        ``supersample_terrain``)."""
        self._mvp = np.asarray(mvp, np.float32)
        self._background = tuple(float(c) for c in background)

    def downsample_into(self, color, row0: int, factor: int):
        """Average this image's ``factor`` x ``factor`` pixel blocks (background where nothing was
        drawn) into rows ``row0``... of the f32 vec3 field ``color`` [0-255], and reset the keys."""
        self._downsample(color, row0, factor, vec3f(self._background))

    def draw(self, vertices, indices, colors, cull=False, share=None, light=None):
        """Draw a mesh: f32 vec3 fields ``vertices`` [m] and ``colors`` (lit, RGB in [0, 1]) and an
        i32 field of triangle corners. ``cull``: skip triangles seen from behind (their corners
        clockwise on screen), for closed surfaces wound counter-clockwise seen from outside;
        ``cull = "front"`` skips those seen from the front instead (a shadow map keeps the far
        side of its casters, see ``shadows.py``). ``share``: f32 field, per vertex the part of its
        colour a shadow removes (``lighting.shade``), kept per pixel for ``finish``. ``light``: the
        key light's position [m] for a closed surface: its triangles turned away from the light are
        in the surface's own shadow, so they are drawn without that share (and need no look-up in
        the shadow map, where they are themselves, at a depth too steep to compare reliably)."""
        mode = -1 if cull == "front" else int(bool(cull))
        pos = vec3f(0.0, 0.0, 0.0) if light is None else vec3f(*map(float, light))
        if share is None:
            self._raster(vertices, indices, colors, colors, 0, mode, self._mvp, pos, 0)
        else:
            self._raster(vertices, indices, colors, share, 1, mode, self._mvp, pos, int(light is not None))

    def finish(self, shadow=None, fine=None, keep: bool = False, color=None) -> np.ndarray:
        """The frame: uint8 RGB [height, width, 3], row 0 at the top.

        ``shadow``: a ``shadows.ShadowPass`` whose map was drawn for this frame: pixels it hides
        from the key light lose their colour's key-light share. ``fine``: a ``shadows.BodyPass``,
        a rasterizer of ``fine.factor`` times this one's width and height into which the bodies
        were drawn (same camera): each pixel in ``fine.rect`` averages its factor x factor samples
        over this image's own (the terrain); 2 antialiases the bodies' silhouettes. The keys of
        ``fine`` are reset for the next frame, and this one's unless ``keep`` (a terrain drawn
        once for a fixed camera). ``color``: an f32 vec3 field [height, width] of this image's
        colours (0-255) drawn with more samples (``downsample_into``), used instead of the keys'.
        """
        image = np.empty((self.height, self.width, 3), np.uint8)
        none = np.zeros(4, np.int32)
        if shadow is None:
            light, bias, srect, smap = np.zeros((3, 4), np.float32), (0.0, 0.0), none, self.key
        else:
            light, bias, srect, smap = shadow.matrix, (shadow.bias, shadow.body_bias), shadow.rect, shadow.raster.key
        frect, fkey, factor = (none, self.key, 1) if fine is None else (fine.rect, fine.raster.key, fine.factor)
        if color is None:
            self._resolve(vec3f(self._background), image, smap, mat34f(light), vec2f(bias), ivec4(srect), fkey,
                          ivec4(frect), factor, int(not keep), self._dummy_color(), 0)
        else:
            self._resolve(vec3f(self._background), image, smap, mat34f(light), vec2f(bias), ivec4(srect), fkey,
                          ivec4(frect), factor, int(not keep), color, 1)
        return image

    def _dummy_color(self):
        if not hasattr(self, "_no_color"):
            self._no_color = ti.Vector.field(3, ti.f32, (1, 1))
        return self._no_color

    def clear(self):
        """Reset every key (a shadow map after its frame; ``finish`` resets its own)."""
        self._clear()

    # -- kernels -------------------------------------------------------------------------------
    @ti.kernel
    def _raster(self, verts: ti.template(), idx: ti.template(), colors: ti.template(), share: ti.template(),
                use_share: ti.template(), cull: ti.i32, mvp: mat4f, light: vec3f, self_shadow: ti.i32):
        height, width = self.key.shape
        scale = ti.Vector([ti.f32(width), ti.f32(height)])
        for t in range(idx.shape[0] // 3):
            i0, i1, i2 = idx[3 * t], idx[3 * t + 1], idx[3 * t + 2]
            m = ti.Matrix.cols([_corner(verts, mvp, scale, i0), _corner(verts, mvp, scale, i1),
                                _corner(verts, mvp, scale, i2)])
            det = m.determinant()
            all_front = m[2, 0] > Z_NEAR and m[2, 1] > Z_NEAR and m[2, 2] > Z_NEAR
            # With every corner in front, det > 0 means clockwise on screen (rows grow downwards):
            # a closed surface wound counter-clockwise from outside shows its back there.
            skip = det == 0.0 or (cull > 0 and all_front and det > 0.0) or (cull < 0 and all_front and det < 0.0)
            # Screen bounding box of the part in front of the near plane: the corners in front and
            # the points where the edges cross it.
            lo = ti.Vector([ti.f32(width), ti.f32(height)])
            hi = ti.Vector([-1.0, -1.0], dt=ti.f32)
            for k in ti.static(range(3)):
                a = ti.Vector([m[0, k], m[1, k], m[2, k]])
                b = ti.Vector([m[0, (k + 1) % 3], m[1, (k + 1) % 3], m[2, (k + 1) % 3]])
                if a[2] >= Z_NEAR:
                    lo = ti.min(lo, a.xy / a[2])
                    hi = ti.max(hi, a.xy / a[2])
                if (a[2] - Z_NEAR) * (b[2] - Z_NEAR) < 0.0:
                    c = a + (Z_NEAR - a[2]) / (b[2] - a[2]) * (b - a)
                    lo = ti.min(lo, c.xy / Z_NEAR)
                    hi = ti.max(hi, c.xy / Z_NEAR)
            # Clamped to just outside the image first: far-off projections would overflow an i32.
            lo = ti.min(ti.max(lo, -1.0), scale + 1.0)
            hi = ti.min(ti.max(hi, -1.0), scale + 1.0)
            # Pixel (col, row) has its centre at (col + 0.5, row + 0.5).
            c0 = ti.max(0, ti.cast(ti.floor(lo[0] - 0.5), ti.i32) + 1)
            c1 = ti.min(width - 1, ti.cast(ti.floor(hi[0] - 0.5), ti.i32))
            r0 = ti.max(0, ti.cast(ti.floor(lo[1] - 0.5), ti.i32) + 1)
            r1 = ti.min(height - 1, ti.cast(ti.floor(hi[1] - 0.5), ti.i32))
            if not skip and c0 <= c1 and r0 <= r1:
                inv = m.inverse()
                rgb = ti.Matrix.cols([colors[i0], colors[i1], colors[i2]]) * 255.0
                sh = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
                if ti.static(use_share):
                    sh = ti.Vector([share[i0], share[i1], share[i2]]) * 255.0
                    if self_shadow != 0:
                        p0 = verts[i0]
                        facing = (verts[i1] - p0).cross(verts[i2] - p0).normalized(1e-20).dot(
                            (light - p0).normalized(1e-20))
                        # Within TERMINATOR of grazing the map is unreliable (its depth changes by
                        # many texels' worth across one texel): on either side the shadow's effect
                        # fades to nothing at facing = 0, so a curved body shows no seam of facets.
                        trust = ti.min(ti.abs(facing) / TERMINATOR, 1.0)
                        if facing <= 0.0:  # turned away from the light: in its own shadow
                            for k in ti.static(range(3)):
                                for ch in ti.static(range(3)):
                                    rgb[ch, k] *= 1.0 - trust * sh[k] / 255.0
                            sh = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
                        else:
                            sh *= trust
                dx = ti.Vector([inv[0, 0], inv[1, 0], inv[2, 0]])  # d b / d column
                for row in range(r0, r1 + 1):
                    b0 = inv @ ti.Vector([0.5, row + 0.5, 1.0], dt=ti.f32)  # b at column 0
                    # The columns where every weight and their sum are >= 0 (each is linear in the
                    # column), widened by a pixel: the exact test below decides the edges.
                    x0, x1 = ti.f32(c0), ti.f32(c1)
                    # The four (weights and their sum) as vectors indexed below: choosing between a
                    # sum and an element inside the unrolled loop crashes Taichi 1.7's scalarize pass
                    # when its IR optimisations are off (runtime.OPTIMIZE_ENV).
                    slopes = ti.Vector([dx[0], dx[1], dx[2], dx.sum()])
                    offsets = ti.Vector([b0[0], b0[1], b0[2], b0.sum()])
                    for k in ti.static(range(4)):
                        slope, offset = slopes[k], offsets[k]
                        if slope > 0.0:
                            x0 = ti.max(x0, -offset / slope - 1.0)
                        elif slope < 0.0:
                            x1 = ti.min(x1, -offset / slope + 1.0)
                        elif offset < 0.0:
                            x1 = -1.0
                    # Kept within the box before the cast: a near-zero slope gives huge bounds.
                    x0, x1 = ti.min(x0, ti.f32(c1 + 1)), ti.max(x1, ti.f32(c0 - 1))
                    for col in range(ti.cast(ti.ceil(x0), ti.i32), ti.cast(ti.floor(x1), ti.i32) + 1):
                        b = b0 + ti.f32(col) * dx
                        s = b.sum()
                        if b[0] >= 0.0 and b[1] >= 0.0 and b[2] >= 0.0 and s > 0.0:
                            w = 1.0 / s  # view depth of the point seen [m]
                            if Z_NEAR <= w <= Z_FAR:
                                c = ti.cast(ti.min(ti.max(rgb @ (b * w) + 0.5, 0.0), 255.0), ti.i64)
                                packed = (c[0] << 16) | (c[1] << 8) | c[2]
                                if ti.static(use_share):
                                    q = ti.cast(ti.min(ti.max(sh.dot(b * w) + 0.5, 0.0), 255.0), ti.i64)
                                    packed |= q << SHARE_SHIFT
                                key = (ti.cast(ti.bit_cast(ti.f32(w), ti.i32), ti.i64) << 32) | packed
                                if key < self.key[row, col]:  # most hidden pixels need no atomic
                                    ti.atomic_min(self.key[row, col], key)

    @ti.kernel
    def _resolve(self, background: vec3f, dst: ti.types.ndarray(dtype=ti.u8, ndim=3), smap: ti.template(),
                 light: mat34f, bias: vec2f, srect: ivec4, fine: ti.template(), frect: ivec4, factor: ti.template(),
                 reset: ti.i32, color: ti.template(), use_color: ti.template()):
        height, width = self.key.shape
        bg = ti.min(ti.max(background, 0.0), 1.0) * 255.0
        for row in range(height):  # one row per task: its bytes are written in order
            for col in range(width):
                key = self.key[row, col]
                c = bg
                if ti.static(use_color):
                    c = color[row, col]
                if key != ti.i64(EMPTY):
                    rgb, share = _unpack(key)
                    if ti.static(use_color):
                        rgb = c
                    c = rgb
                    # Shadows only where the casters' shadow volume can be seen (``srect``).
                    if srect[0] <= col < srect[2] and srect[1] <= row < srect[3] and share > 0.0:
                        lit = _lit(smap, light, bias[0], col + 0.5, row + 0.5, _depth(key))
                        c = rgb * (1.0 - share * (1.0 - lit))
                    if reset:
                        self.key[row, col] = ti.i64(EMPTY)
                if frect[0] <= col < frect[2] and frect[1] <= row < frect[3]:
                    # factor x factor samples of the bodies over this pixel's terrain colour.
                    acc = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
                    for k in ti.static(range(factor * factor)):
                        r, q = factor * row + k // factor, factor * col + k % factor
                        sample = fine[r, q]
                        if sample < key:
                            rgb, share = _unpack(sample)
                            if srect[0] <= col < srect[2] and srect[1] <= row < srect[3] and share > 0.0:
                                lit = _lit(smap, light, bias[1], (q + 0.5) / factor, (r + 0.5) / factor, _depth(sample))
                                rgb *= 1.0 - share * (1.0 - lit)
                            acc += rgb
                            fine[r, q] = ti.i64(EMPTY)
                        else:
                            acc += c
                    c = acc / (factor * factor)
                for ch in ti.static(range(3)):
                    dst[row, col, ch] = ti.cast(ti.min(c[ch] + 0.5, 255.0), ti.u8)

    @ti.kernel
    def _downsample(self, color: ti.template(), row0: ti.i32, factor: ti.i32, background: vec3f):
        height, width = self.key.shape
        bg = ti.min(ti.max(background, 0.0), 1.0) * 255.0
        for row, col in ti.ndrange(height // factor, width // factor):
            acc = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
            for i, j in ti.ndrange(factor, factor):
                key = self.key[factor * row + i, factor * col + j]
                if key == ti.i64(EMPTY):
                    acc += bg
                else:
                    acc += _unpack(key)[0]
                    self.key[factor * row + i, factor * col + j] = ti.i64(EMPTY)
            if row0 + row < color.shape[0]:
                color[row0 + row, col] = acc / ti.f32(factor * factor)

    @ti.kernel
    def _clear(self):
        for row, col in self.key:
            self.key[row, col] = ti.i64(EMPTY)
