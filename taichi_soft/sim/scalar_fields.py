"""Setting several 0-D fields (scalars, small vectors) from Python in one kernel launch.

Writing a 0-D field from Python (``f[None] = v``) runs a writer kernel that Taichi compiles for
that field, and for each component of a vector field, the first time: about 20 ms each on the
2-core VM. A simulation's terrain, model and integrator set 19-86 of them as they are built; in
the test suite, which builds hundreds of simulations, those compiles were 10 % of the CPU time
(py-spy over a cold-cache run, 2026-12-06). ``assign`` writes any number of them with one kernel,
compiled once per set of fields (25-60 ms for 5-15 fields), then about 0.3 ms a launch.

The values go through f64 and are cast to each field's type in the kernel: the same rounding as
Taichi's own writer for f32 fields, exact for integer values in i32 fields.
"""
import numpy as np
import taichi as ti


def assign(values: dict):
    """Write ``{field: value}``: 0-D scalar fields take a number (or bool), 0-D vector fields a
    sequence of their length. Nothing to write launches nothing."""
    if not values:
        return
    fields, layout, flat = [], [], []
    for f, v in values.items():
        fields.append(f)
        if isinstance(f, ti.lang.matrix.MatrixField):
            components = [float(c) for c in v]
            if len(components) != f.n:
                raise ValueError(f"{f.n} components expected, got {len(components)}")
            layout.append((len(flat), f.n))
            flat += components
        else:
            layout.append((len(flat), 0))
            flat.append(float(v))
    _assign(tuple(fields), tuple(layout), np.array(flat, dtype=np.float64))


@ti.kernel
def _assign(fields: ti.template(), layout: ti.template(), flat: ti.types.ndarray(dtype=ti.f64, ndim=1)):
    # layout[k] = (first index in flat, components: 0 for a scalar field)
    for k in ti.static(range(len(fields))):
        if ti.static(layout[k][1] == 0):
            fields[k][None] = ti.cast(flat[layout[k][0]], fields[k].dtype)
        else:
            for c in ti.static(range(layout[k][1])):
                fields[k][None][c] = ti.cast(flat[layout[k][0] + c], fields[k].dtype)
