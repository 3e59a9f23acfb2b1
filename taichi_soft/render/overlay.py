"""Text drawn onto rendered frames with Pillow (headless GGUI leaves ImGui out of saved images).

Everything works on uint8 RGB arrays [height, width, 3] in place and only touches the pixels
under the text panels, so an overlay costs about a millisecond per frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

# Fonts tried in order (Pillow searches the system font folders); the last resort is Pillow's
# own scalable default font, which every Pillow >= 10.1 built with FreeType has.
_FONTS = {"regular": ("DejaVuSansMono.ttf", "LiberationMono-Regular.ttf", "Menlo.ttc", "consola.ttf"),
          "bold": ("DejaVuSans-Bold.ttf", "LiberationSans-Bold.ttf", "Arial Bold.ttf", "arialbd.ttf")}
PANEL = (12, 16, 24)  # dark backing behind text, drawn at PANEL_ALPHA
PANEL_ALPHA = 0.62
TEXT = (240, 242, 245)
ALERT = (215, 38, 38)
INFO_MARGIN = 0.14  # fraction of the height the info panel covers at the top (cameras keep it clear)
INFO_LINES = 3  # the lines INFO_MARGIN holds (``RunInfo.lines`` without extra lines)


@lru_cache(maxsize=32)
def font(size: int, weight: str = "regular") -> ImageFont.ImageFont:
    """A TrueType font of ``size`` pixels (monospaced for ``regular``, so numbers do not jitter)."""
    for name in _FONTS[weight]:
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


@dataclass(frozen=True)
class RunInfo:
    """What the overlay says about a run: fixed labels plus the current time and energy."""

    scene: str
    integrator: str
    dt: float  # s
    stiffness: str  # already formatted, e.g. "2000 N/m" or "600..8000 N/m"
    damping: str  # e.g. "60 N s/m"
    extra: tuple = ()  # further fixed lines under the others (the run's error estimate)

    def lines(self, time: float, energy_change: float) -> list[str]:
        """Overlay lines at simulated ``time`` [s] with the total energy's change since t = 0 [J]."""
        return [f"{self.scene} | {self.integrator} | dt = {self.dt:g} s",
                f"k = {self.stiffness} | damping = {self.damping}",
                f"t = {time:7.3f} s | {ENERGY_LABEL} = {energy_text(energy_change)}", *self.extra]


def info_margin(lines: int) -> float:
    """Fraction of the height an info panel of ``lines`` lines covers (``draw_info``'s default size)."""
    return INFO_MARGIN + max(0, lines - INFO_LINES) * 1.3 / 34


# Labels show the total energy's change since the start: its value depends on where gravity's
# zero is (y = 0: 88 kJ at the start of the default drop), which buried the dissipation and
# drift a class looks for; the change since t = 0 does not.
ENERGY_LABEL = "E - E(0)"


def energy_text(energy: float) -> str:
    """An energy (change) [J] for labels, signed: 0.1 J below 1 kJ, whole joules up to 10 MJ, else
    scientific (short enough for the subtitle of a compare tile)."""
    if not math.isfinite(energy) or abs(energy) >= 1e7:
        return f"{energy:+.3g} J"
    return f"{energy:+.1f} J" if abs(energy) < 1e3 else f"{energy:+.0f} J"


def value_range(values, unit: str) -> str:
    """``"2000 N/m"`` if all values are equal, else ``"600..8000 N/m"``."""
    lo, hi = float(np.min(values)), float(np.max(values))
    return f"{lo:g} {unit}" if lo == hi else f"{lo:g}..{hi:g} {unit}"


def run_info(sim, extra=()) -> RunInfo:
    """The overlay labels of a ``Simulation``: stiffness and damping read from the model's fields
    (so values changed at run time show), as one value or a range over bodies and spring kinds;
    ``extra`` lines go under them."""
    m = sim.model
    return RunInfo(sim.scene.label, sim.integrator_name, sim.dt,
                   value_range(m.group_k.to_numpy(), "N/m"), value_range(m.group_kd.to_numpy(), "N s/m"), tuple(extra))


def _panel(img: np.ndarray, box, text_rows, fill=PANEL, alpha=PANEL_ALPHA):
    """Blend a backing rectangle ``box`` = (x0, y0, x1, y1) into ``img`` and draw text rows on it.

    ``text_rows`` = [(x, y, text, font, colour)] in image coordinates.
    """
    h, w = img.shape[:2]
    x0, y0, x1, y1 = max(0, box[0]), max(0, box[1]), min(w, box[2]), min(h, box[3])
    if x1 <= x0 or y1 <= y0:
        return
    region = img[y0:y1, x0:x1].astype(np.float32)
    region = region * (1 - alpha) + np.asarray(fill, np.float32) * alpha
    patch = Image.fromarray(region.astype(np.uint8))
    draw = ImageDraw.Draw(patch)
    for x, y, text, f, colour in text_rows:
        draw.text((x - x0, y - y0), text, font=f, fill=colour)
    img[y0:y1, x0:x1] = np.asarray(patch)


def _text_size(text: str, f) -> tuple[int, int]:
    """(width, line height) in pixels; the height is the font's, so every label of a size matches."""
    ascent, descent = f.getmetrics() if hasattr(f, "getmetrics") else (f.getbbox("Ag")[3], 0)
    return f.getbbox(text)[2], ascent + descent


def draw_info(img: np.ndarray, lines: list[str], size: int | None = None) -> None:
    """Lines of text in a panel at the top left; ``size`` [px] defaults to 1/34 of the height
    (three lines then fill ``INFO_MARGIN`` of it)."""
    h = img.shape[0]
    size = size or max(9, round(h / 34))
    f = font(size)
    pad, step = max(2, size // 3), round(size * 1.3)
    width = max(_text_size(line, f)[0] for line in lines)
    rows = [(2 * pad, 2 * pad + k * step, line, f, TEXT) for k, line in enumerate(lines)]
    _panel(img, (pad, pad, 3 * pad + width, 3 * pad + len(lines) * step - (step - size)), rows)


def draw_banner(img: np.ndarray, text: str, size: int | None = None, y: float = 0.5) -> None:
    """``text`` centred in a red band across the image at height fraction ``y`` (0 = top)."""
    h, w = img.shape[:2]
    size = size or max(10, round(h / 12))
    f = font(size, "bold")
    while size > 8 and _text_size(text, f)[0] > 0.94 * w:  # shrink to fit narrow tiles
        size -= 1
        f = font(size, "bold")
    tw, th = _text_size(text, f)
    pad = max(3, size // 3)
    top = int(y * h - (th + 2 * pad) / 2)
    _panel(img, (0, top, w, top + th + 2 * pad), [((w - tw) // 2, top + pad, text, f, (255, 255, 255))],
           fill=ALERT, alpha=0.88)


def title_sizes(height: int, width: int, title: str, subtitle: str = "") -> tuple[int, int]:
    """Font sizes [px] (title, subtitle) of a ``draw_title`` label on a ``width`` x ``height`` tile.

    Both scale with the tile: the title 1/11 of its height, the subtitle 0.7 of the title (at
    least 10 px, readable in a 640 x 360 mosaic of four tiles), each shrunk until it fits the
    tile's width.
    """
    size = max(11, round(height / 11))
    small = max(10, round(0.7 * size))
    while size > 9 and _text_size(title, font(size, "bold"))[0] > 0.94 * width:
        size -= 1
    while subtitle and small > 8 and _text_size(subtitle, font(small))[0] > 0.94 * width:
        small -= 1
    return size, small


def draw_title(img: np.ndarray, title: str, subtitle: str = "", size: int | None = None) -> None:
    """A big label (compare tiles) at the bottom left: bold ``title`` over a smaller ``subtitle``
    (sizes from ``title_sizes`` unless ``size`` fixes the title's).

    At the bottom because default cameras put the foreground terrain there, not the bodies.
    """
    h, w = img.shape[:2]
    auto, small_size = title_sizes(h, w, title, subtitle)
    size = size or auto
    big, small = font(size, "bold"), font(small_size)
    pad = max(2, size // 5)
    tw, th = _text_size(title, big)
    sw, sh = _text_size(subtitle, small) if subtitle else (0, 0)
    height = pad + th + (pad + sh if subtitle else 0) + 2 * pad
    top = h - height
    rows = [(2 * pad, top + pad, title, big, TEXT)]
    if subtitle:
        rows.append((2 * pad, top + 2 * pad + th, subtitle, small, TEXT))
    _panel(img, (0, top, max(tw, sw) + 4 * pad, h), rows)


def dim(img: np.ndarray, amount: float = 0.35) -> None:
    """Darken and desaturate ``img`` in place (a frozen, diverged tile)."""
    grey = img.mean(axis=2, keepdims=True)
    img[:] = ((0.5 * img + 0.5 * grey) * (1 - amount)).astype(np.uint8)
