"""sim/scalar_fields.assign: several 0-D fields written in one kernel hold exactly what Taichi's own
per-field writer would have stored."""
import numpy as np
import pytest
import taichi as ti

from taichi_soft.sim.scalar_fields import assign


def test_assign_stores_what_the_field_writer_stores_in_every_type():
    values = {"f64": 0.1, "f32": 0.1, "i32": 2**31 - 1, "flag": True, "vec": (0.1, -2.5, 1e-30)}

    def fields():
        return {"f64": ti.field(ti.f64, ()), "f32": ti.field(ti.f32, ()), "i32": ti.field(ti.i32, ()),
                "flag": ti.field(ti.i32, ()), "vec": ti.Vector.field(3, ti.f32, ())}

    ours, theirs = fields(), fields()
    assign({ours[k]: v for k, v in values.items()})
    for k, v in values.items():
        theirs[k][None] = v
    for k in values:
        a, b = np.asarray(ours[k].to_numpy()), np.asarray(theirs[k].to_numpy())
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), (k, a, b)
    assert ours["f32"][None] != 0.1 and ours["i32"][None] == 2**31 - 1 and ours["flag"][None] == 1


def test_assign_writes_only_the_fields_given_and_checks_vector_lengths():
    a, b, v = ti.field(ti.f64, ()), ti.field(ti.f64, ()), ti.Vector.field(3, ti.f64, ())
    assign({a: 1.0, b: 2.0})
    assign({b: 3.0})
    assign({})  # nothing to write
    assert (a[None], b[None]) == (1.0, 3.0)
    with pytest.raises(ValueError, match="3 components expected, got 2"):
        assign({v: (1.0, 2.0)})
