"""Photographic textures for the simulated rooms, taken from the photos bundled with scikit-image.

Real photographs give ORB corners, blobs and edges the statistics of real images, which flat colours and
procedural checkerboards do not. Every texture is a named `TextureSource`: which scikit-image image it
comes from, an optional colour tint (most of the bundled textures are grey), and the licence stated in
scikit-image's `skimage/data/_fetchers.py`. `bags/README.md` lists the same table.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.texture_gen import EMISSION, GENERATED

U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class TextureSource:
    """One texture: a scikit-image photo, an optional RGB tint (multiplier in [0, 1]) and its licence."""

    skimage_name: str
    tint_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    licence: str = ""
    what: str = ""
    rot90: bool = False  # turn the photo a quarter turn (the brick photo has vertical courses)
    crop: tuple[int, int, int, int] | None = None  # (row0, row1, col0, col1) of the photo, before the tint
    wrap_fraction: float | None = None  # the crop covers this fraction of the width; the rest is its top rows
    grey: bool = False  # drop the photo's colour before the tint


# name used in scenes -> where it comes from. Licences as stated by scikit-image's data docstrings.
TEXTURES: dict[str, TextureSource] = {
    "brick": TextureSource("brick", (0.85, 0.55, 0.45), "CC0 (CC0Textures Bricks25)", "brick wall", True),
    "brick_grey": TextureSource("brick", (0.8, 0.8, 0.78), "CC0 (CC0Textures Bricks25)", "painted brick wall",
                                True),
    "plaster": TextureSource("moon", (1.0, 0.93, 0.8), "no separate statement; scikit-image BSD-3-Clause",
                             "plastered wall"),
    "wallpaper": TextureSource("grass", (0.7, 0.78, 0.9), "CC0 (DeviantArt, linolafett Grass-01)", "wallpaper"),
    "stucco": TextureSource("gravel", (0.95, 0.92, 0.85), "CC0 (CC0Textures Gravel04)", "stucco wall"),
    "gravel": TextureSource("gravel", (0.75, 0.65, 0.55), "CC0 (CC0Textures Gravel04)", "floor"),
    "grass": TextureSource("grass", (0.45, 0.7, 0.35), "CC0 (DeviantArt, linolafett Grass-01)", "rug, plant"),
    "coins": TextureSource("coins", (0.9, 0.85, 0.6), "no known copyright restrictions (Brooklyn Museum)",
                           "poster"),
    "text": TextureSource("text", (1.0, 1.0, 0.95), "public domain (Wikipedia File:Corner.png)", "notice board"),
    "page": TextureSource("page", (1.0, 0.98, 0.9), "no separate statement; scikit-image BSD-3-Clause",
                          "book, shelf"),
    "hubble": TextureSource("hubble_deep_field", licence="public domain (NASA)", what="poster, monitor screen"),
    "rocket": TextureSource("rocket", licence="public domain (SpaceX)", what="poster, monitor screen"),
    "coffee": TextureSource("coffee", licence="CC0 (Rachel Michetti)", what="cup, poster"),
    "chelsea": TextureSource("chelsea", licence="CC0 (Stefan van der Walt)", what="teddy-bear fur"),
    "astronaut": TextureSource("astronaut", licence="public domain (NASA; Eileen Collins)", what="person"),
    "cameraman": TextureSource("camera", (0.95, 0.9, 0.85), "CC0 (Lav Varshney)", "person"),
    "clock": TextureSource("clock", (0.9, 0.9, 1.0), "public domain (Stefan van der Walt)", "poster"),
    "moon": TextureSource("moon", (0.95, 0.95, 0.92), "no separate statement; scikit-image BSD-3-Clause",
                          "ceiling, plaster"),
    "retina": TextureSource("retina", licence="CC0 1.0 (Häggström, WikiJournal of Medicine)", what="poster"),
    "ihc": TextureSource("immunohistochemistry", licence="no known copyright restrictions (CMMI)",
                         what="poster"),
    "suit_orange": TextureSource("moon", (0.95, 0.45, 0.15), "no separate statement; scikit-image BSD-3-Clause",
                                 "orange suit"),
    "fabric_dark": TextureSource("gravel", (0.25, 0.25, 0.35), "CC0 (CC0Textures Gravel04)", "trousers, plastic"),
    "wood": TextureSource("grass", (0.6, 0.42, 0.25), "CC0 (DeviantArt, linolafett Grass-01)", "furniture"),
    "leather": TextureSource("moon", (0.45, 0.25, 0.15), "no separate statement; scikit-image BSD-3-Clause",
                             "suitcase, chair"),
    # people: skin, clothes, and heads (a face photo wrapped on the front of an ellipsoid, hair around)
    "skin": TextureSource("moon", (1.0, 0.78, 0.62), "no separate statement; scikit-image BSD-3-Clause", "skin"),
    "shirt_red": TextureSource("gravel", (0.85, 0.22, 0.18), "CC0 (CC0Textures Gravel04)", "shirt"),
    "shoe": TextureSource("gravel", (0.18, 0.13, 0.1), "CC0 (CC0Textures Gravel04)", "shoes"),
    "denim": TextureSource("grass", (0.35, 0.45, 0.75), "CC0 (DeviantArt, linolafett Grass-01)", "jeans"),
    "shirt_blue": TextureSource("coins", (0.45, 0.6, 0.95), "no known copyright restrictions (Brooklyn Museum)",
                                "shirt", grey=True),
    "head_astronaut": TextureSource("astronaut", licence="public domain (NASA; Eileen Collins)", what="head",
                                    crop=(28, 178, 150, 295), wrap_fraction=0.36),
    "head_grey": TextureSource("astronaut", (0.75, 0.68, 0.62), "public domain (NASA; Eileen Collins)", "head",
                               crop=(28, 178, 150, 295), wrap_fraction=0.36, grey=True),
    "plastic_blue": TextureSource("coins", (0.3, 0.45, 0.85), "no known copyright restrictions (Brooklyn Museum)",
                                  "the unknown object"),
    # the same photos shown on a lit screen (`texture_gen.EMISSION`)
    "screen_rocket": TextureSource("rocket", licence="public domain (SpaceX)", what="monitor screen"),
    "screen_astronaut": TextureSource("astronaut", licence="public domain (NASA; Eileen Collins)",
                                      what="monitor screen"),
}


def load_texture(name: str) -> U8:
    """The texture `name` as an (H, W, 3) uint8 RGB image, tinted.

    Raises SimError for an unknown name. Loads from the scikit-image data folder (no network), or draws one
    of `texture_gen.GENERATED`.
    """
    if name in GENERATED:
        return GENERATED[name]()
    try:
        source = TEXTURES[name]
    except KeyError as err:
        known = ", ".join(sorted({*TEXTURES, *GENERATED}))
        raise SimError(f"texture {name!r}: unknown; known: {known}") from err
    import skimage.data

    try:
        image = getattr(skimage.data, source.skimage_name)()
    except Exception as err:  # noqa: BLE001 - scikit-image raises several kinds here
        raise SimError(f"texture {name!r}: cannot load skimage.data.{source.skimage_name} ({err})") from err
    if isinstance(image, tuple):  # stereo pairs: take the left image
        image = image[0]
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.stack([image] * 3, axis=-1)
    image = image[..., :3].astype(np.float32)
    if source.grey:
        image = np.repeat(image.mean(axis=2, keepdims=True), 3, axis=2)
    if source.crop is not None:
        r0, r1, c0, c1 = source.crop
        image = image[r0:r1, c0:c1]
    if source.wrap_fraction is not None:
        image = _wrapped(image, source.wrap_fraction)
    if source.rot90:
        image = np.ascontiguousarray(np.rot90(image))
    image *= np.asarray(source.tint_rgb, dtype=np.float32)
    return np.clip(image + 0.5, 0, 255).astype(np.uint8)


def _wrapped(face: npt.NDArray[np.float32], fraction: float) -> npt.NDArray[np.float32]:
    """A texture to wrap around a head: `face` in the middle covering `fraction` of the width, the rest
    filled with its top rows (hair) stretched, blended into the face over a tenth of its width."""
    h, w = face.shape[:2]
    width = int(round(w / fraction))
    hair = cv2.resize(face[: max(2, h // 8)], (width, h), interpolation=cv2.INTER_LINEAR)
    out = hair.copy()
    x0 = (width - w) // 2
    ramp = np.clip(np.minimum(np.arange(w) + 1, w - np.arange(w)) / max(1.0, 0.1 * w), 0.0, 1.0)
    alpha = ramp[None, :, None].astype(np.float32)
    out[:, x0:x0 + w] = alpha * face + (1.0 - alpha) * hair[:, x0:x0 + w]
    return out


@functools.lru_cache(maxsize=64)
def texture_png(name: str) -> bytes:
    """The texture `name` as PNG bytes, ready for MuJoCo; cached per process (textures never change)."""
    return png_bytes(load_texture(name))


def texture_emission(name: str) -> float:
    """Material emission (0-1) of the texture `name`: above 0 only for lit screens."""
    return EMISSION.get(name, 0.0)


def png_bytes(image_rgb: U8) -> bytes:
    """Encode an (H, W, 3) uint8 RGB image as PNG bytes (deterministic)."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise SimError("texture: PNG encoding failed")
    return bytes(buf.tobytes())
