"""The Taichi rasterizer's look, ``--quality`` (``taichi_renderer.TaichiRenderer``; GGUI ignores it).

``low``: what GGUI draws (the checker filtered for its footprint, one sample a pixel, no
shadows); ``medium``: + the bodies' shadows from the key light; ``high``: + the bodies' edges with
2 x 2 samples a pixel and, for a fixed camera, the terrain with 4 x 4. The default was chosen by
measurement (docs/benchmarks/RENDERING.md, "Shadows and anti-aliasing"). Imports nothing heavy: the CLI
validates the choice before Taichi starts.
"""
from ..errors import UserError

QUALITIES = ("low", "medium", "high")
DEFAULT_QUALITY = "high"


def check_quality(quality: str) -> str:
    """``quality`` if it is one of ``QUALITIES``, else ``UserError`` naming them."""
    if quality not in QUALITIES:
        raise UserError(f"unknown quality {quality!r}; choose one of: {', '.join(QUALITIES)}")
    return quality
