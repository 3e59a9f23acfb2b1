"""Which offscreen renderer draws a run's frames (``--renderer auto|ggui|taichi``).

``ggui``: a hidden GGUI window through Vulkan (``renderer.Renderer``): everything (surfaces,
terrain, particles, springs), fast on a GPU, ~3x slower than ``taichi`` on Mesa's lavapipe.
``taichi``: Taichi kernels on the CPU (``taichi_renderer.TaichiRenderer``, ``raster.py``): surfaces and
terrain, no Vulkan needed. ``auto``: ggui where Vulkan offers a GPU or the frame needs particles
or springs, else taichi. Both draw the same lit vertex colours (docs/rendering.md).

Nothing here imports Taichi at module level: the CLI validates the choice before Taichi starts.
"""
from __future__ import annotations

from ..errors import UserError
from .quality import DEFAULT_QUALITY, check_quality

RENDERERS = ("auto", "ggui", "taichi")


def choose_renderer(kind: str = "auto", needs_ggui: bool = False) -> str:
    """``"ggui"`` or ``"taichi"`` for ``--renderer kind``; ``needs_ggui``: particles or springs are
    drawn. Raises ``UserError`` for an unknown kind or taichi with particles/springs."""
    if kind not in RENDERERS:
        raise UserError(f"unknown renderer {kind!r}; choose one of: {', '.join(RENDERERS)}")
    if kind == "auto":
        from .vkinfo import has_gpu_vulkan

        return "ggui" if needs_ggui or has_gpu_vulkan() else "taichi"
    if kind == "taichi" and needs_ggui:
        raise UserError("--renderer taichi draws surfaces and terrain only; --particles and --springs need "
                        "--renderer ggui (or auto)")
    return kind


def make_renderer(width: int, height: int, kind: str = "auto", needs_ggui: bool = False,
                  quality: str = DEFAULT_QUALITY):
    """The renderer ``choose_renderer`` picks, ``width`` x ``height`` pixels (Taichi initialised);
    ``quality`` shapes the Taichi rasterizer's frames (GGUI draws no shadows and one sample a pixel).
    A GGUI one without a usable Vulkan device raises ``NoVulkanDevice`` (one line)."""
    from .renderer import Renderer
    from .taichi_renderer import TaichiRenderer

    check_quality(quality)
    if choose_renderer(kind, needs_ggui) == "ggui":
        return Renderer(width, height)
    return TaichiRenderer(width, height, quality)
