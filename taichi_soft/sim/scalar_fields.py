"""Setting several 0-D fields (scalars, small vectors) from Python in one kernel launch.

Writing a 0-D field from Python (``f[None] = v``) runs a writer kernel that Taichi compiles for
that field, and for each component of a vector field, the first time; a simulation sets dozens as
it is built. ``assign`` writes a set of fields with one kernel, compiled once per set: what it
saves is the compiles (docs/decisions/batched-scalar-writes.md).

The values travel as f64 and are cast to each field's type in the kernel: the same rounding as
Taichi's own writer for f32 fields, exact for integers in i32 fields (others are refused). On a
backend without f64 (Metal, some Vulkan devices) each field is written by Taichi's writer instead.

Taichi keys the kernel on the field objects themselves (a template argument), so each set written
stays referenced for the life of the process: a few hundred bytes per simulation built.
"""
import numpy as np
import taichi as ti

_INT_RANGE = {ti.i32: (-2**31, 2**31 - 1)}
_F64_ARCHS = (ti.x64, ti.arm64, ti.cuda)  # backends whose kernels take f64 whatever the precision


def assign(values: dict):
    """Write ``{field: value}``: a 0-D scalar field (f32, f64 or i32) takes a number or a bool, a
    0-D vector field a sequence of its length. Nothing to write launches nothing."""
    if not values:
        return
    fields, layout, flat = [], [], []
    for f, v in values.items():
        if f.shape != ():
            raise ValueError(f"assign writes 0-D fields only, not shape {f.shape}")
        fields.append(f)
        if isinstance(f, ti.lang.matrix.MatrixField):
            if f.m != 1:
                raise ValueError(f"assign writes vector fields only, not {f.n} x {f.m} matrices")
            components = [float(c) for c in v]
            if len(components) != f.n:
                raise ValueError(f"{f.n} components expected, got {len(components)}")
            layout.append((len(flat), f.n))
            flat += components
        else:
            layout.append((len(flat), 0))
            flat.append(_number(f, v))
    if ti.lang.impl.current_cfg().arch not in _F64_ARCHS:
        for f, (first, n) in zip(fields, layout):
            f[None] = tuple(flat[first:first + n]) if n else int(flat[first]) if f.dtype in _INT_RANGE else flat[first]
        return
    _assign(tuple(fields), tuple(layout), np.array(flat, dtype=np.float64))


def _number(f, v) -> float:
    """``v`` as the f64 the kernel casts to ``f``'s type; an integer field takes integers in its range."""
    if f.dtype in _INT_RANGE:
        lo, hi = _INT_RANGE[f.dtype]
        if int(v) != v or not lo <= v <= hi:
            raise ValueError(f"{v!r} is not an integer an {f.dtype} field holds")
        return float(int(v))
    if f.dtype not in (ti.f32, ti.f64):
        raise ValueError(f"assign writes f32, f64 and i32 fields, not {f.dtype}")
    return float(v)


@ti.kernel
def _assign(fields: ti.template(), layout: ti.template(), flat: ti.types.ndarray(dtype=ti.f64, ndim=1)):
    # layout[k] = (first index in flat, components: 0 for a scalar field)
    for k in ti.static(range(len(fields))):
        if ti.static(layout[k][1] == 0):
            fields[k][None] = ti.cast(flat[layout[k][0]], fields[k].dtype)
        else:
            for c in ti.static(range(layout[k][1])):
                fields[k][None][c] = ti.cast(flat[layout[k][0] + c], fields[k].dtype)
