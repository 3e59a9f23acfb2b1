"""taichi_soft.compile_speed: Taichi's front end without source excerpts or repeated source reads
still compiles the same kernels and still says where a compile error is."""
import pytest
import taichi as ti

from conftest import restart_taichi
from taichi_soft.workarounds import compile_speed


def test_installed_on_the_pinned_taichi():
    # runtime.init (the module's Taichi runtime, tests/conftest.py) installs it; a Taichi upgrade
    # that moves the patched functions fails here instead of silently compiling slower.
    assert compile_speed.install()
    from taichi.lang import kernel_impl

    assert kernel_impl._get_tree_and_ctx is compile_speed._tree_and_ctx
    from taichi.lang import impl, snode

    assert impl.get_traceback is snode.get_traceback is compile_speed._declaration_traceback


@ti.func
def _cube(x):
    return x * x * x


def test_kernels_calling_functions_many_times_compute_what_they_say():
    out = ti.field(ti.f64, shape=8)

    @ti.kernel
    def fill():
        for i in out:
            s = 0.0
            for j in ti.static(range(3)):  # the same ti.func transformed three times per loop body
                s += _cube(ti.cast(i, ti.f64) + j)
            out[i] = s

    fill()
    got = out.to_numpy()
    assert all(got[i] == i**3 + (i + 1) ** 3 + (i + 2) ** 3 for i in range(8))


def test_a_compile_error_still_names_the_file_line_and_function():
    @ti.kernel
    def broken() -> ti.f64:
        return undefined_name * 2.0  # noqa: F821

    with pytest.raises(Exception) as err:
        broken()
    text = str(err.value)
    assert "undefined_name" in text and __file__ in text and "in broken" in text
    line = next(i for i, src in enumerate(open(__file__), 1) if "return undefined_name" in src)
    assert f"line {line}" in text, text


def _declare_without_shape():
    return ti.field(ti.f64)


def test_an_unplaced_field_is_still_said_with_where_it_was_declared():
    # The declaration note keeps the innermost frames only (compile_speed.DECLARATION_FRAMES):
    # the function that declared the field and its caller are among them.
    _declare_without_shape()
    with pytest.raises(RuntimeError) as err:
        ti.field(ti.f64, shape=2)[0] = 1.0  # materialising the runtime finds the unplaced field
    text = str(err.value)
    assert "not placed" in text and __file__ in text, text
    assert "in _declare_without_shape" in text and "in test_an_unplaced_field_is_still_said" in text, text


def test_optimised_runs_skip_only_the_cfg_pass(taichi_runtime):
    """runtime.SKIP_CFG_PASS: with optimisation on, every IR pass but the control-flow-graph one
    (its cost grows faster than the kernel); with it off, none."""
    from taichi_soft import runtime

    assert runtime.SKIP_CFG_PASS
    try:
        runtime.init("cpu", "f64", optimize=True)
        cfg = ti.lang.impl.current_cfg()
        assert cfg.advanced_optimization and not cfg.cfg_optimization
        runtime.init("cpu", "f64", optimize=False)
        assert not ti.lang.impl.current_cfg().advanced_optimization
    finally:
        restart_taichi(taichi_runtime)  # the module's runtime again
