"""sim/scalar_fields.assign: 0-D f64, f32 and i32 scalar and vector fields written in one kernel hold
the bits Taichi's own per-field writer stores; what it cannot store exactly it refuses."""
import numpy as np
import pytest
import taichi as ti

from taichi_soft.sim.scalar_fields import assign


def test_assign_stores_what_the_field_writer_stores():
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


def test_assign_refuses_what_it_would_store_wrongly():
    i, m, a = ti.field(ti.i32, ()), ti.Matrix.field(2, 2, ti.f64, ()), ti.field(ti.f64, 3)
    for value in (2**31, 2.5):
        with pytest.raises(ValueError, match="integer an i32 field holds"):
            assign({i: value})
    with pytest.raises(ValueError, match="vector fields only"):
        assign({m: (1.0, 2.0, 3.0, 4.0)})
    with pytest.raises(ValueError, match="0-D fields only"):
        assign({a: 1.0})


def test_without_f64_each_field_is_written_by_taichis_writer(monkeypatch):
    from taichi_soft.sim import scalar_fields

    monkeypatch.setattr(scalar_fields, "_F64_ARCHS", ())  # as on Metal: no f64 in kernels
    f, i, v = ti.field(ti.f32, ()), ti.field(ti.i32, ()), ti.Vector.field(2, ti.f32, ())
    assign({f: 0.1, i: True, v: (0.5, -1.0)})
    assert f[None] == np.float32(0.1) and i[None] == 1 and tuple(v[None]) == (0.5, -1.0)
