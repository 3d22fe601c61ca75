"""Textures drawn in code for the furniture looks (`sim/furniture.py`): leaves, pots, upholstery, hard shells,
clock faces, screens, bottle glass and labels.

Each generator is deterministic (a fixed noise seed per texture) and returns an (H, W, 3) uint8 RGB image.
The photos of `sim/textures.py` cover walls, floors and posters; these cover the surfaces that no bundled photo
shows: a leaf's veins, a clock's dial, a woven sofa fabric. `GENERATED` maps each texture name to its
generator; `EMISSION` gives the screens their own light, so a monitor's picture stays bright in a dim room.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]


def _noise(shape: tuple[int, int], scale_px: float, seed: int) -> F32:
    """Smooth noise in [-1, 1]: white noise blurred at `scale_px` and normalised."""
    rng = np.random.default_rng(seed)
    n = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), scale_px)
    return np.asarray(n / (np.abs(n).max() + 1e-6), dtype=np.float32)


def _tinted(grey: F32, rgb: tuple[float, float, float]) -> U8:
    """A grey level image in [0, 1] times a colour (0-255 per channel)."""
    out = grey[..., None] * np.asarray(rgb, dtype=np.float32)[None, None, :]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def leaf(rgb: tuple[float, float, float], seed: int) -> U8:
    """A leaf seen flat: a pale midrib down the middle (and down the back, u = 0), side veins slanting up
    from it, mottled shading, a darker rim; wrapped around an ellipsoid its front shows one leaf blade."""
    h, w = 256, 256
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    g = 0.78 + 0.12 * _noise((h, w), 6.0, seed) + 0.06 * _noise((h, w), 1.5, seed + 1)
    for cx in (w / 2, 0.0, float(w)):  # midribs at the front and (wrapped) at the back
        d = np.abs(x - cx)
        g += 0.35 * np.exp(-(d / 2.5) ** 2)
        side = np.abs(((y + 0.9 * d) % 28.0) - 14.0)  # veins slanting towards the tip
        g += 0.12 * np.exp(-(side / 1.6) ** 2) * (d < w / 4)
    edge = np.minimum(np.abs(x - w / 4), np.abs(x - 3 * w / 4))  # the blade's edges, seen from the front
    g *= 1.0 - 0.25 * np.exp(-(edge / 6.0) ** 2)
    g *= 0.85 + 0.15 * (1.0 - y / h)  # lighter towards the tip (top)
    return _tinted(np.clip(g, 0.0, 1.3), rgb)


def glazed(rgb: tuple[float, float, float], seed: int, bands: bool) -> U8:
    """A pot or a hard case: a smooth colour with a fine grain, a lighter vertical sheen, optional rings."""
    h, w = 128, 256
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    g = 0.85 + 0.05 * _noise((h, w), 3.0, seed) + 0.03 * _noise((h, w), 0.8, seed + 1)
    g += 0.18 * np.exp(-((x - 0.42 * w) / (0.05 * w)) ** 2)  # a sheen a little left of the front
    if bands:
        g -= 0.25 * (np.abs(y - 0.14 * h) < 3) + 0.15 * (np.abs(y - 0.9 * h) < 2)
    return _tinted(g, rgb)


def ribbed(rgb: tuple[float, float, float], seed: int) -> U8:
    """A hard-shell suitcase face: vertical ribs (light and shadow), a fine grain."""
    h, w = 256, 256
    x = np.mgrid[0:h, 0:w][1].astype(np.float32)
    g = 0.8 + 0.18 * np.sin(2 * np.pi * x / 32.0) ** 7 - 0.1 * np.sin(2 * np.pi * (x + 4) / 32.0) ** 15
    g += 0.04 * _noise((h, w), 1.0, seed)
    return _tinted(g, rgb)


def weave(rgb: tuple[float, float, float], seed: int) -> U8:
    """A woven upholstery fabric: threads crossing every 4 px, slub noise, soft blotches of wear."""
    h, w = 256, 256
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    warp = 0.5 + 0.5 * np.cos(np.pi * x / 2.0) * np.sign(np.sin(np.pi * (y + 1) / 4.0))
    g = 0.82 + 0.08 * warp + 0.06 * _noise((h, w), 1.0, seed) + 0.08 * _noise((h, w), 14.0, seed + 1)
    return _tinted(g, rgb)


def clock_face(dark: bool, numerals: bool, seed: int) -> U8:
    """A round dial filling the image (a disk on a cylinder's cap): hour and minute marks, numerals 1-12 or
    bars, hour, minute and a red second hand. Drawn a quarter turn clockwise, so that on a cylinder turned to
    face +x (pitch -pi/2) it reads upright."""
    s = 512
    c = s // 2
    bg, ink = ((30, 30, 34), (235, 235, 230)) if dark else ((246, 244, 236), (20, 20, 22))
    img = np.full((s, s, 3), bg, np.uint8)
    for k in range(60):
        a = 2 * np.pi * k / 60
        r0 = 0.80 if k % 5 else 0.72
        p0 = (int(c + r0 * c * np.sin(a)), int(c - r0 * c * np.cos(a)))
        p1 = (int(c + 0.9 * c * np.sin(a)), int(c - 0.9 * c * np.cos(a)))
        cv2.line(img, p0, p1, ink, 10 if k % 5 == 0 else 3, cv2.LINE_AA)
    if numerals:
        for hr in range(1, 13):
            a = 2 * np.pi * hr / 12
            txt = str(hr)
            (tw, th), _ = cv2.getTextSize(txt, cv2.FONT_HERSHEY_DUPLEX, 1.6, 4)
            px, py = c + 0.58 * c * np.sin(a) - tw / 2, c - 0.58 * c * np.cos(a) + th / 2
            cv2.putText(img, txt, (int(px), int(py)), cv2.FONT_HERSHEY_DUPLEX, 1.6, ink, 4, cv2.LINE_AA)
    rng = np.random.default_rng(seed)
    hour, minute = rng.uniform(0, 12), rng.uniform(0, 60)
    for frac, length, width, col in ((hour / 12, 0.45, 16, ink), (minute / 60, 0.7, 10, ink),
                                     (rng.uniform(0, 1), 0.78, 3, (200, 30, 30))):
        a = 2 * np.pi * frac
        cv2.line(img, (c, c), (int(c + length * c * np.sin(a)), int(c - length * c * np.cos(a))), col, width,
                 cv2.LINE_AA)
    cv2.circle(img, (c, c), 14, ink, -1, cv2.LINE_AA)
    return np.ascontiguousarray(np.rot90(img, k=1))


def desktop(seed: int) -> U8:
    """A lit computer screen: a blue-to-teal wallpaper, two application windows, a task bar with icons."""
    h, w = 360, 640
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.stack([40 + 60 * x / w, 90 + 80 * y / h, 170 + 60 * (1 - y / h)], axis=-1)
    img += 12 * _noise((h, w), 30.0, seed)[..., None]
    img = np.clip(img, 0, 255).astype(np.uint8)
    rng = np.random.default_rng(seed)
    for _ in range(2):
        x0, y0 = int(rng.uniform(20, 300)), int(rng.uniform(15, 120))
        x1, y1 = x0 + int(rng.uniform(220, 320)), y0 + int(rng.uniform(150, 200))
        cv2.rectangle(img, (x0, y0), (x1, y1), (245, 245, 245), -1)
        cv2.rectangle(img, (x0, y0), (x1, y0 + 22), (60, 60, 70), -1)
        for k, yy in enumerate(range(y0 + 36, y1 - 10, 16)):
            cv2.line(img, (x0 + 12, yy), (x0 + 12 + int(rng.uniform(60, x1 - x0 - 30)), yy), (90, 90, 100), 4)
    cv2.rectangle(img, (0, h - 28), (w, h), (25, 25, 30), -1)
    for k in range(8):
        cv2.rectangle(img, (12 + 34 * k, h - 22), (36 + 34 * k, h - 6),
                      tuple(int(v) for v in rng.integers(80, 255, 3)), -1)
    return img


def label(rgb: tuple[float, float, float], seed: int) -> U8:
    """A bottle label wrapped around: a coloured band, a white panel at the front with a brand line and small
    print, thin gold rules top and bottom."""
    h, w = 128, 512
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = rgb
    cv2.rectangle(img, (w // 2 - 70, 18), (w // 2 + 70, h - 18), (240, 236, 225), -1)
    rng = np.random.default_rng(seed)
    letters = "".join(chr(int(v)) for v in rng.integers(65, 91, 5))
    cv2.putText(img, letters, (w // 2 - 62, 62), cv2.FONT_HERSHEY_TRIPLEX, 1.2, (30, 30, 30), 2, cv2.LINE_AA)
    for k in range(3):
        cv2.line(img, (w // 2 - 55, 80 + 10 * k), (w // 2 + 55, 80 + 10 * k), (110, 110, 110), 2)
    for yy in (6, h - 7):
        cv2.line(img, (0, yy), (w, yy), (200, 170, 80), 4)
    return img


def plain(rgb: tuple[float, float, float], seed: int, grain: float = 0.05) -> U8:
    """A nearly flat colour with a fine grain (bezels, metal, soil)."""
    g = 1.0 + grain * _noise((128, 128), 1.2, seed) + grain * _noise((128, 128), 8.0, seed + 1)
    return _tinted(g, rgb)


GENERATED: dict[str, Callable[[], U8]] = {
    "leaf_green": lambda: leaf((70, 140, 50), 1),
    "leaf_dark": lambda: leaf((40, 100, 45), 2),
    "leaf_yellow": lambda: leaf((120, 160, 60), 3),
    "pot_terracotta": lambda: glazed((190, 95, 55), 4, bands=True),
    "pot_white": lambda: glazed((225, 222, 214), 5, bands=False),
    "pot_grey": lambda: glazed((95, 98, 104), 6, bands=True),
    "soil": lambda: plain((70, 50, 35), 7, 0.25),
    "fabric_grey": lambda: weave((150, 150, 155), 8),
    "fabric_beige": lambda: weave((200, 180, 150), 9),
    "fabric_green": lambda: weave((90, 120, 90), 10),
    "fabric_blue": lambda: weave((70, 90, 140), 11),
    "shell_black": lambda: ribbed((55, 55, 60), 12),
    "shell_navy": lambda: ribbed((40, 55, 100), 13),
    "shell_red": lambda: ribbed((170, 40, 40), 14),
    "shell_silver": lambda: ribbed((185, 188, 192), 15),
    "clock_white": lambda: clock_face(False, True, 16),
    "clock_bars": lambda: clock_face(False, False, 17),
    "clock_black": lambda: clock_face(True, True, 18),
    "screen_desktop": lambda: desktop(19),
    "label_red": lambda: label((170, 35, 35), 20),
    "label_blue": lambda: label((40, 70, 150), 21),
    "glass_green": lambda: glazed((50, 110, 60), 22, bands=False),
    "glass_brown": lambda: glazed((110, 60, 25), 23, bands=False),
    "plastic_clear": lambda: glazed((175, 200, 215), 24, bands=False),
    "black_plastic": lambda: plain((28, 28, 30), 25),
    "metal": lambda: plain((165, 168, 172), 26, 0.08),
    "rim_silver": lambda: plain((190, 190, 195), 27, 0.04),
}

# texture name -> material emission (0-1): screens light themselves
EMISSION: dict[str, float] = {"screen_desktop": 0.5, "screen_rocket": 0.5, "screen_astronaut": 0.5}
