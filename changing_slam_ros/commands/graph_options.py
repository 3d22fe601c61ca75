"""The graph's option values parsed before any process starts: `--nice NODE=N`, `--kill NODE@S`, `--load-map MAP@S`."""

from __future__ import annotations

from pathlib import Path

from changing_slam_ros.errors import ConfigError


def parse_nice(specs: list[str], known: tuple[str, ...]) -> dict[str, int]:
    """`--nice NODE=N` specs as {node: increment}; an unknown node or a value outside 0..19 is a ConfigError."""
    out: dict[str, int] = {}
    for spec in specs:
        name, _, value = spec.partition("=")
        if name not in known:
            raise ConfigError(f"--nice {spec}: unknown node {name!r} (nodes: {', '.join(known)})")
        try:
            out[name] = int(value)
        except ValueError as err:
            raise ConfigError(f"--nice {spec}: expected NODE=N with N an integer 0..19, e.g. local_mapping=5") from err
        if not 0 <= out[name] <= 19:
            raise ConfigError(f"--nice {spec}: N must be 0..19 (raising a priority needs privileges)")
    return out


def parse_at(specs: list[str], option: str, example: str) -> list[tuple[str, float]]:
    """WHAT@SECONDS arguments (--kill, --load-map) -> (what, seconds); the last @ splits (a path may hold one)."""
    out = []
    for spec in specs:
        what, _, seconds = spec.rpartition("@")
        try:
            out.append((what, float(seconds)))
        except ValueError as err:
            raise ConfigError(f"{option} {spec}: expected {example}") from err
    return out


def parse_loads(specs: list[str]) -> list[tuple[str, float]]:
    """--load-map MAP@S -> (absolute map path, seconds); a missing or bad map fails here, before anything starts."""
    from changing_slam_ros.io.map_file import load_map

    loads = parse_at(specs, "--load-map", "MAP@SECONDS, e.g. first/map.npz@4")
    for path, _ in loads:
        load_map(path)
    return [(str(Path(path).resolve()), at_s) for path, at_s in loads]


def parse_kills(specs: list[str]) -> list[tuple[str, float]]:
    return parse_at(specs, "--kill", "NODE@SECONDS, e.g. object_map@5")
