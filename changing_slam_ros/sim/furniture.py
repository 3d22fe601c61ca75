"""Furniture looks for the randomised changing rooms: objects built to look like their COCO class.

`actors.py`'s catalogue keeps the plain block shapes the hand-made scenarios were made with; here each class
has several styles drawn the way the real things are built: a potted plant of leaves around a stem in a
tapered pot, a round clock with a rim and a dial, a couch with arms and cushions, a suitcase with wheels and
handles, a monitor with a thin bezel, a lit screen and a stand, a bottle with shoulders, neck, cap and label,
chairs with padded, slatted, upholstered or office backs. `look_parts(kind, style, rng)` builds one; every
size, colour and leaf angle comes from `rng`, so a seed fixes the look. Frames as in `actors.py`: z up, origin
at the centre of the footprint on the floor (a wall item: its back centre on the wall), front facing +x.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.actors import Part, Shape
from changing_slam_ros.sim.draws import between

B, C, E = Shape.BOX, Shape.CYLINDER, Shape.ELLIPSOID
HALF_PI = float(np.pi / 2)


def _pick(rng: np.random.Generator, options: tuple[str, ...]) -> str:
    return options[int(rng.integers(len(options)))]


def _r3(v: np.ndarray | tuple[float, float, float]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def rod(a: tuple[float, float, float], b: tuple[float, float, float], radius_m: float, texture: str,
        tile_m: float | None = 0.2, shape: Shape = C) -> Part:
    """A cylinder (or a box of square section, or an ellipsoid) from point `a` to point `b`."""
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    d = pb - pa
    length = float(np.linalg.norm(d))
    horiz = float(np.hypot(d[0], d[1]))
    # the part's z axis turned by pitch about y (towards +x for a negative pitch), then by yaw about z
    pitch = -float(np.arctan2(horiz, d[2]))
    yaw = float(np.arctan2(d[1], d[0])) if horiz > 1e-9 else 0.0
    return Part((radius_m, radius_m, length / 2), _r3((pa + pb) / 2), texture, tile_m, shape, pitch, yaw)


def leaf(base: tuple[float, float, float], azimuth_rad: float, elevation_rad: float, length_m: float,
         width_m: float, texture: str) -> Part:
    """A flat leaf blade (a thin ellipsoid) growing from `base` towards `azimuth_rad`, `elevation_rad` above
    the horizontal; the midrib of the leaf texture runs along its length."""
    d = np.array([np.cos(elevation_rad) * np.cos(azimuth_rad), np.cos(elevation_rad) * np.sin(azimuth_rad),
                  np.sin(elevation_rad)])
    centre = np.asarray(base, float) + d * length_m / 2
    return Part((0.006, width_m / 2, length_m / 2), _r3(centre), texture, None, E,
                -(HALF_PI - elevation_rad), azimuth_rad)


def _pot(rng: np.random.Generator, radius_m: float, height_m: float, texture: str) -> list[Part]:
    """A pot narrowing towards its foot (three stacked cylinders), a rim and the soil inside."""
    parts = []
    n = 3
    for k in range(n):
        r = radius_m * (0.78 + 0.22 * (k + 0.5) / n)
        hz = height_m / (2 * n)
        parts.append(Part((r, r, hz), (0.0, 0.0, hz * (2 * k + 1)), texture, None, C))
    rim = radius_m * 1.06
    parts.append(Part((rim, rim, 0.018), (0.0, 0.0, height_m + 0.006), texture, None, C))
    parts.append(Part((radius_m * 0.95, radius_m * 0.95, 0.01), (0.0, 0.0, height_m + 0.016), "soil", 0.1, C))
    return parts


POT_TEXTURES = ("pot_terracotta", "pot_white", "pot_grey")
LEAF_TEXTURES = ("leaf_green", "leaf_dark", "leaf_yellow")


def potted_plant(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A potted plant, 0.6-1.3 m: "bushy" (broad leaves arching out of the soil), "tree" (a trunk carrying
    clusters of small leaves) or "upright" (long blades standing up, a snake plant)."""
    pot_r, pot_h = between(rng, 0.13, 0.18), between(rng, 0.22, 0.32)
    parts = _pot(rng, pot_r, pot_h, _pick(rng, POT_TEXTURES))
    top = pot_h + 0.02
    leaf_tex = _pick(rng, LEAF_TEXTURES)
    if style == "bushy":
        n = int(rng.integers(22, 32))
        for k in range(n):
            az = 2.4 * k + between(rng, -0.3, 0.3)  # the golden angle: leaves spread evenly round the stem
            el = between(rng, 0.35, 1.35)
            base = (between(rng, -0.03, 0.03), between(rng, -0.03, 0.03), top + between(rng, 0.0, 0.15))
            parts.append(leaf(base, float(az), el, between(rng, 0.28, 0.45), between(rng, 0.08, 0.13), leaf_tex))
        parts.append(Part((0.015, 0.015, 0.1), (0.0, 0.0, top + 0.08), "leaf_dark", 0.1, C))
    elif style == "tree":
        trunk_h = between(rng, 0.55, 0.8)
        parts.append(Part((0.018, 0.018, trunk_h / 2), (0.0, 0.0, top + trunk_h / 2), "wood", 0.2, C))
        n_clusters = int(rng.integers(4, 7))
        for j in range(n_clusters):
            a = 2 * np.pi * j / n_clusters + between(rng, -0.3, 0.3)
            rad = between(rng, 0.08, 0.2)
            cz = top + trunk_h * between(rng, 0.55, 1.05)
            centre = (rad * np.cos(a), rad * np.sin(a), cz)
            parts.append(rod((0.0, 0.0, cz - 0.12), _r3(centre), 0.008, "wood", 0.2))
            for _ in range(int(rng.integers(9, 14))):
                parts.append(leaf(centre, between(rng, -np.pi, np.pi), between(rng, -0.6, 1.2), between(rng, 0.12, 0.2),
                                  between(rng, 0.05, 0.08), leaf_tex))
    elif style == "upright":
        n = int(rng.integers(9, 15))
        for k in range(n):
            az = between(rng, -np.pi, np.pi)
            base = (0.6 * pot_r * np.cos(az) * between(rng, 0.0, 1.0), 0.6 * pot_r * np.sin(az) * between(rng, 0.0, 1.0), top)
            parts.append(leaf(_r3(base), az, between(rng, 1.2, 1.5), between(rng, 0.45, 0.8), between(rng, 0.06, 0.09), leaf_tex))
    else:
        raise SimError(f"potted plant: unknown style {style!r}")
    return tuple(parts)


def wall_clock(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A round wall clock, 0.24-0.36 m across, its dial facing +x, origin at its back centre on the wall: a
    rim ("black", "silver" or "wood") and a dial slightly in front of it."""
    rim_tex = {"black": "black_plastic", "silver": "rim_silver", "wood": "wood"}.get(style)
    if rim_tex is None:
        raise SimError(f"wall clock: unknown style {style!r}")
    r = between(rng, 0.12, 0.18)
    depth = between(rng, 0.035, 0.05)
    face = _pick(rng, ("clock_white", "clock_bars", "clock_black") if style != "wood" else ("clock_white",))
    fr = r * between(rng, 0.84, 0.9)
    return (
        Part((r, r, depth / 2), (depth / 2, 0.0, 0.0), rim_tex, 0.1, C, -HALF_PI),
        Part((fr, fr, 0.003), (depth + 0.002, 0.0, 0.0), face, None, C, -HALF_PI),
    )


FABRICS = ("fabric_grey", "fabric_beige", "fabric_green", "fabric_blue", "leather", "fabric_dark")


def couch(style: str, rng: np.random.Generator, length_m: float | None = None) -> tuple[Part, ...]:
    """A two- or three-seat couch facing +x, 1.4-2.0 m long, 0.9 m deep, 0.85 m tall: legs, a base, seat
    cushions, back cushions leaning back, and arms: "square" or "rolled" (a round bolster on top)."""
    if style not in ("square", "rolled"):
        raise SimError(f"couch: unknown style {style!r}")
    length = length_m if length_m is not None else between(rng, 1.4, 2.0)
    tex = _pick(rng, FABRICS)
    hy, arm_w = length / 2, between(rng, 0.12, 0.16) if style == "square" else between(rng, 0.14, 0.2)
    n_seats = 3 if length > 1.7 else 2
    inner = hy - arm_w
    parts = [Part((0.02, 0.02, 0.05), (sx * 0.38, sy * (hy - 0.06), 0.05), "wood", 0.2, C)
             for sx in (-1, 1) for sy in (-1, 1)]
    parts.append(Part((0.43, hy, 0.1), (0.0, 0.0, 0.2), tex, 0.35))  # base frame
    parts.append(Part((0.1, hy, 0.3), (-0.35, 0.0, 0.5), tex, 0.35))  # back frame
    w = inner / n_seats
    for k in range(n_seats):
        y = -inner + w * (2 * k + 1)
        parts.append(Part((0.3, w - 0.008, 0.07), (0.1, y, 0.37), tex, 0.35))  # seat cushion
        parts.append(Part((0.09, w - 0.012, 0.22), (-0.2, y, 0.62), tex, 0.35, B, 0.22))  # back cushion
    arm_top = between(rng, 0.55, 0.65)
    for sy in (-1, 1):
        y = sy * (hy - arm_w / 2)
        if style == "square":
            parts.append(Part((0.43, arm_w / 2, (arm_top - 0.1) / 2), (0.0, y, (arm_top - 0.1) / 2 + 0.1), tex, 0.35))
            parts.append(Part((0.44, arm_w / 2 + 0.01, 0.03), (0.01, y, arm_top - 0.01), tex, 0.35))  # arm pad
        else:
            parts.append(Part((0.41, arm_w / 2 - 0.01, (arm_top - 0.1) / 2), (0.0, y, (arm_top - 0.1) / 2 + 0.08),
                              tex, 0.35))
            parts.append(Part((arm_w / 2 + 0.02, arm_w / 2 + 0.02, 0.43), (0.0, y, arm_top - 0.02), tex, 0.35, C,
                              -HALF_PI))
    if rng.random() < 0.6:  # throw pillows at the ends
        pt = _pick(rng, tuple(f for f in FABRICS if f != tex))
        for sy in (-1, 1):
            parts.append(Part((0.06, 0.19, 0.17), (-0.1, sy * (inner - 0.22), 0.6), pt, None, B, 0.35))
    return tuple(parts)


def _rounded_slab(half_m: tuple[float, float, float], radius_m: float, z_m: float, texture: str,
                  tile_m: float | None) -> list[Part]:
    """A box centred at (0, 0, `z_m`) whose four edges along x are rounded with `radius_m` (a suitcase's shell
    seen from the front): two crossed boxes and a cylinder along x in each corner."""
    hx, hy, hz = half_m
    r = radius_m
    return [Part((hx, hy - r, hz), (0.0, 0.0, z_m), texture, tile_m), Part((hx, hy, hz - r), (0.0, 0.0, z_m), texture,
                                                                          tile_m)] + [
        Part((r, r, hx), (0.0, sy * (hy - r), z_m + sz * (hz - r)), texture, tile_m, C, -HALF_PI)
        for sy in (-1, 1) for sz in (-1, 1)]


SHELLS = ("shell_black", "shell_navy", "shell_red", "shell_silver")


def suitcase(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """An upright suitcase on four spinner wheels, its wide face to +x: "hard" (ribbed shell, seam) or "soft"
    (fabric with a front pocket); a carry handle on top and a telescopic handle, retracted or pulled out."""
    hx, hy, hz = between(rng, 0.1, 0.13), between(rng, 0.19, 0.24), between(rng, 0.28, 0.36)
    z0 = 0.07
    zc = z0 + hz
    rc = 0.055  # radius of the shell's rounded corners
    if style == "hard":
        tex = _pick(rng, SHELLS)
        parts = _rounded_slab((0.008, hy + 0.003, hz + 0.003), rc + 0.003, zc, "rim_silver", 0.1)  # zip seam
    elif style == "soft":
        tex = _pick(rng, ("fabric_dark", "fabric_blue", "fabric_grey", "fabric_green"))
        parts = [Part((0.025, hy * 0.8, hz * 0.55), (hx + 0.02, 0.0, zc - 0.2 * hz), tex, 0.3),  # pocket
                 Part((0.004, hy * 0.8, 0.006), (hx + 0.046, 0.0, zc + 0.12 * hz), "black_plastic", 0.1)]
    else:
        raise SimError(f"suitcase: unknown style {style!r}")
    tile = None if style == "hard" else 0.3
    parts += _rounded_slab((hx, hy, hz), rc, zc, tex, tile)  # the shell
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * (hx - 0.03), sy * (hy - 0.03)
            parts.append(Part((0.018, 0.018, 0.012), (x, y, z0 - 0.012), "black_plastic", 0.1, C))  # housing
            parts.append(Part((0.025, 0.025, 0.01), (x, y, 0.025), "black_plastic", 0.1, C, HALF_PI, HALF_PI))
    top = zc + hz
    parts += [rod((0.0, -0.06, top), (0.0, -0.06, top + 0.035), 0.01, "black_plastic"),
              rod((0.0, 0.06, top), (0.0, 0.06, top + 0.035), 0.01, "black_plastic"),
              rod((0.0, -0.07, top + 0.04), (0.0, 0.07, top + 0.04), 0.014, "black_plastic")]
    ext = between(rng, 0.25, 0.45) if rng.random() < 0.6 else 0.0
    xb = -hx + 0.02
    for sy in (-1, 1):
        parts.append(rod((xb, sy * 0.12, top - 0.02), (xb, sy * 0.12, top + 0.02 + ext), 0.009, "metal"))
    parts.append(Part((0.018, 0.14, 0.015), (xb, 0.0, top + 0.035 + ext), "black_plastic", 0.1))
    return tuple(parts)


# what a screen shows: a desktop or a launch; a television also shows people. Not a still life filling the
# screen (a cup photo on a black frame reads as a framed picture, and the family hangs that photo as one)
SCREENS = ("screen_desktop", "screen_rocket")
TV_SCREENS = SCREENS + ("screen_astronaut",)


def monitor(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A computer monitor standing on a table top (z = 0), screen to +x: a thin black bezel, a lit picture,
    a housing at the back, a neck and a foot: "round" (disc foot) or "flat" (a flat rectangular foot)."""
    w = between(rng, 0.26, 0.34)  # half width; 16:9
    h = w * 9 / 16
    screen = _pick(rng, SCREENS)
    zc = between(rng, 0.1, 0.16) + h + 0.02
    parts = [
        Part((0.012, w, h), (0.0, 0.0, zc), "black_plastic", 0.1),  # bezel
        Part((0.002, w - 0.012, h - 0.012), (0.013, 0.0, zc), screen, None),  # picture
        Part((0.025, w * 0.55, h * 0.55), (-0.035, 0.0, zc), "black_plastic", 0.1),  # housing
        Part((0.015, 0.035, (zc - 0.01) / 2), (-0.07, 0.0, (zc - 0.01) / 2 + 0.01), "black_plastic", 0.1),  # neck
    ]
    if style == "round":
        parts.append(Part((0.11, 0.11, 0.008), (-0.05, 0.0, 0.008), "black_plastic", 0.1, C))
    elif style == "flat":
        parts.append(Part((0.09, 0.13, 0.008), (-0.05, 0.0, 0.008), "metal", 0.1))
    else:
        raise SimError(f"monitor: unknown style {style!r}")
    return tuple(parts)


def wall_screen(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A flat screen hung on a wall, 0.6-0.9 m wide, 3 cm deep, a thin black bezel round a lit picture;
    "plain" or "soundbar" (a speaker bar under it). Origin at its back centre on the wall."""
    w = between(rng, 0.3, 0.45)
    h = w * 9 / 16
    screen = _pick(rng, TV_SCREENS)
    parts = [Part((0.015, w, h), (0.015, 0.0, 0.0), "black_plastic", 0.1),
             Part((0.002, w - 0.012, h - 0.012), (0.031, 0.0, 0.0), screen, None)]
    if style == "soundbar":
        parts.append(Part((0.035, w * 0.8, 0.03), (0.035, 0.0, -h - 0.06), "fabric_dark", 0.1))
    elif style != "plain":
        raise SimError(f"wall screen: unknown style {style!r}")
    return tuple(parts)


BOTTLE_BODIES = ("glass_green", "glass_brown", "plastic_clear", "plastic_blue")


def bottle(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A bottle standing on z = 0: body, rounded shoulder, neck, cap and a label round the body; "wine"
    (tall, long neck) or "water" (shorter, wide, short neck)."""
    if style == "wine":
        r, body_h, neck_h, neck_r = between(rng, 0.035, 0.04), between(rng, 0.17, 0.2), between(rng, 0.07, 0.09), 0.014
        body = _pick(rng, ("glass_green", "glass_brown"))
    elif style == "water":
        r, body_h, neck_h, neck_r = between(rng, 0.035, 0.045), between(rng, 0.15, 0.2), between(rng, 0.02, 0.03), 0.016
        body = _pick(rng, ("plastic_clear", "plastic_blue"))
    else:
        raise SimError(f"bottle: unknown style {style!r}")
    shoulder = r * 1.2
    cap = _pick(rng, ("black_plastic", "rim_silver", "shell_red", "shell_navy"))
    lab = _pick(rng, ("label_red", "label_blue"))
    z = body_h
    return (
        Part((r, r, body_h / 2), (0.0, 0.0, body_h / 2), body, None, C),
        Part((r + 0.001, r + 0.001, body_h * 0.25), (0.0, 0.0, body_h * 0.45), lab, None, C),
        Part((r, r, shoulder / 2), (0.0, 0.0, z), body, None, E),
        Part((neck_r, neck_r, neck_h / 2), (0.0, 0.0, z + shoulder / 2 + neck_h / 2 - 0.01), body, None, C),
        Part((neck_r + 0.002, neck_r + 0.002, 0.012), (0.0, 0.0, z + shoulder / 2 + neck_h + 0.002), cap, None, C),
    )


def chair(style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """A chair facing +x, seat at 0.44-0.48 m: "padded" (wooden frame, cushion, padded back), "slatted"
    (wooden seat, a back of vertical slats under a top rail), "armchair" (upholstered, arms) or "office"
    (a five-star base on casters, gas lift, seat, curved back and arms)."""
    seat_z = between(rng, 0.44, 0.48)
    hw = between(rng, 0.2, 0.24)
    wood = "wood"
    parts: list[Part] = []
    if style in ("padded", "slatted"):
        lean = between(rng, 0.08, 0.18)
        top_z = seat_z + between(rng, 0.38, 0.48)
        for sy in (-1, 1):
            parts.append(Part((0.018, 0.018, seat_z / 2), (hw - 0.03, sy * (hw - 0.03), seat_z / 2), wood, 0.2))
            back_foot = (-hw + 0.03, sy * (hw - 0.03), 0.0)
            back_top = (-hw + 0.03 - lean * (top_z - seat_z), sy * (hw - 0.03), top_z)
            parts.append(rod(back_foot, (back_foot[0], back_foot[1], seat_z), 0.018, wood, 0.2, B))
            parts.append(rod((back_foot[0], back_foot[1], seat_z), back_top, 0.018, wood, 0.2, B))
            parts.append(Part((hw - 0.04, 0.01, 0.015), (0.0, sy * (hw - 0.03), 0.16), wood, 0.2))  # stretcher
        bx = -hw + 0.03 - lean * (top_z - seat_z) / 2
        if style == "padded":
            tex = _pick(rng, FABRICS)
            parts.append(Part((hw, hw, 0.025), (0.0, 0.0, seat_z - 0.005), wood, 0.2))
            parts.append(Part((hw - 0.01, hw - 0.02, 0.035), (0.01, 0.0, seat_z + 0.04), tex, 0.3))
            back_h = (top_z - seat_z) * 0.33
            parts.append(Part((0.03, hw - 0.04, back_h), (bx + 0.015, 0.0, (seat_z + top_z) / 2 + 0.06), tex, 0.3, B,
                              lean))
        else:
            parts.append(Part((hw, hw, 0.02), (0.0, 0.0, seat_z), wood, 0.2))
            parts.append(Part((0.016, hw - 0.01, 0.045), (bx - lean * (top_z - seat_z) / 2 + 0.01, 0.0, top_z - 0.04),
                              wood, 0.2, B, lean))
            n = int(rng.integers(3, 6))
            for k in range(n):
                y = (hw - 0.06) * (2 * k / (n - 1) - 1)
                parts.append(Part((0.008, 0.02, (top_z - seat_z) / 2 - 0.06), (bx, y, (seat_z + top_z) / 2 - 0.01),
                                  wood, 0.2, B, lean))
    elif style == "armchair":
        tex = _pick(rng, FABRICS)
        hw = between(rng, 0.32, 0.38)
        # splayed legs; their foot starts 4 mm up so that the tilted round foot just touches the floor
        parts += [rod((sx * 0.3, sy * (hw - 0.05), 0.004), (sx * 0.28, sy * (hw - 0.07), 0.16), 0.018, wood, 0.2)
                  for sx in (-1, 1) for sy in (-1, 1)]
        parts.append(Part((0.34, hw, 0.07), (0.0, 0.0, 0.23), tex, 0.3))  # seat frame
        parts.append(Part((0.28, hw - 0.08, 0.06), (0.05, 0.0, 0.36), tex, 0.3))  # seat cushion
        parts.append(Part((0.07, hw, 0.32), (-0.29, 0.0, 0.58), tex, 0.3, B, 0.18))  # back
        parts.append(Part((0.07, hw - 0.1, 0.2), (-0.2, 0.0, 0.56), tex, 0.3, B, 0.18))  # back cushion
        for sy in (-1, 1):
            parts.append(Part((0.3, 0.04, 0.12), (0.02, sy * (hw - 0.04), 0.42), tex, 0.3))  # arm
            parts.append(Part((0.32, 0.05, 0.02), (0.03, sy * (hw - 0.04), 0.55), wood, 0.2))  # arm rest
    elif style == "office":
        tex = _pick(rng, ("fabric_dark", "black_plastic", "fabric_blue", "fabric_grey"))
        for k in range(5):
            a = 2 * np.pi * k / 5 + between(rng, -0.2, 0.2)
            end = (0.3 * np.cos(a), 0.3 * np.sin(a), 0.07)
            parts.append(rod((0.0, 0.0, 0.09), _r3(end), 0.016, "black_plastic", 0.1, B))
            parts.append(Part((0.025, 0.025, 0.02), (end[0], end[1], 0.02), "black_plastic", 0.1, E))  # caster
        parts.append(Part((0.025, 0.025, (seat_z - 0.12) / 2), (0.0, 0.0, (seat_z + 0.12) / 2 - 0.02), "metal", 0.1, C))
        parts.append(Part((hw + 0.02, hw + 0.02, 0.045), (0.0, 0.0, seat_z), tex, 0.25))
        parts.append(rod((-0.14, 0.0, seat_z), (-hw - 0.04, 0.0, seat_z + 0.18), 0.02, "black_plastic", 0.1, B))
        parts.append(Part((0.03, hw, 0.22), (-hw - 0.06, 0.0, seat_z + 0.35), tex, 0.25, B, 0.12))
        if rng.random() < 0.7:
            for sy in (-1, 1):
                parts.append(Part((0.01, 0.012, 0.1), (0.0, sy * (hw + 0.02), seat_z + 0.12), "black_plastic", 0.1))
                parts.append(Part((0.13, 0.03, 0.015), (0.0, sy * (hw + 0.02), seat_z + 0.22), "black_plastic", 0.1))
    else:
        raise SimError(f"chair: unknown style {style!r}")
    return tuple(parts)


# catalogue kind of the changing-room family -> (styles, builder)
LOOKS: dict[str, tuple[tuple[str, ...], Callable[[str, np.random.Generator], tuple[Part, ...]]]] = {
    "chair": (("padded", "slatted", "armchair", "office"), chair),
    "couch": (("square", "rolled"), couch),
    "potted_plant": (("bushy", "tree", "upright"), potted_plant),
    "suitcase": (("hard", "soft"), suitcase),
    "monitor": (("round", "flat"), monitor),
    "bottle": (("wine", "water"), bottle),
    "wall_clock": (("black", "silver", "wood"), wall_clock),
    "wall_tv": (("plain", "soundbar"), wall_screen),
}


def look_parts(kind: str, style: str, rng: np.random.Generator) -> tuple[Part, ...]:
    """The parts of a `kind` object (a key of `LOOKS`) in `style`, its sizes and colours drawn from `rng`."""
    try:
        _, build = LOOKS[kind]
    except KeyError as err:
        raise SimError(f"furniture: unknown kind {kind!r}; known: {', '.join(LOOKS)}") from err
    return build(style, rng)


def draw_look(kind: str, rng: np.random.Generator) -> tuple[str, tuple[Part, ...]]:
    """A style of `kind` drawn from `rng`, and its parts."""
    styles, _ = LOOKS[kind]
    style = styles[int(rng.integers(len(styles)))]
    return style, look_parts(kind, style, rng)
