"""RVL depth compression (A. D. Wilson, "Fast Lossless Depth Image Compression", ISS 2017).

Used by image_transport's `compressedDepth` plugin with the `rvl` codec. The stream is a sequence of
variable-length integers of 3-bit groups ("nibbles": 3 data bits plus a continuation bit 0x8, least
significant group first), packed eight nibbles to a little-endian 32-bit word from its high end.
The values alternate: a run of zero pixels, a run of non-zero pixels, then one zig-zag coded delta
to the previous non-zero pixel for each pixel of the run.

`decode_rvl` is vectorised over the nibbles and loops in Python once per run (not per pixel);
`encode_rvl` is a plain reference encoder for writing test data.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def decode_rvl(data: bytes, num_pixels: int) -> npt.NDArray[np.uint16]:
    """RVL words -> (num_pixels,) uint16. ValueError when the stream ends early or overruns."""
    n_words = len(data) // 4
    words = np.frombuffer(data[: n_words * 4], dtype="<u4")
    shifts = np.arange(28, -4, -4, dtype=np.uint32)
    nibbles = ((words[:, None] >> shifts[None, :]) & 0xF).astype(np.int64).reshape(-1)
    if nibbles.size == 0:
        if num_pixels == 0:
            return np.zeros(0, np.uint16)
        raise ValueError("empty RVL stream")
    # group nibbles into values: a value ends at a nibble without the continuation bit
    ends = np.flatnonzero((nibbles & 0x8) == 0)
    if ends.size == 0:
        raise ValueError("RVL stream holds no complete value")
    used = int(ends[-1]) + 1  # nibbles after the last complete value are dropped
    starts = np.concatenate([[0], ends[:-1] + 1])
    pos = np.arange(used) - np.repeat(starts, ends - starts + 1)
    if int(pos.max()) > 20:
        raise ValueError("RVL value longer than 63 bits: not an RVL stream")
    contrib = (nibbles[:used] & 0x7) << (3 * pos)
    values = np.add.reduceat(contrib, starts)

    out = np.zeros(num_pixels, dtype=np.int64)
    deltas: list[npt.NDArray[np.int64]] = []
    positions: list[npt.NDArray[np.int64]] = []
    i = pixel = 0
    n_values = values.size
    while pixel < num_pixels:
        if i + 1 >= n_values:
            raise ValueError(f"RVL stream ends after {pixel} of {num_pixels} pixels")
        zeros, nonzeros = int(values[i]), int(values[i + 1])
        pixel += zeros
        if pixel + nonzeros > num_pixels:
            raise ValueError(f"RVL run overruns the image ({pixel + nonzeros} > {num_pixels} pixels)")
        if i + 2 + nonzeros > n_values:
            raise ValueError(f"RVL stream ends after {pixel} of {num_pixels} pixels")
        deltas.append(values[i + 2 : i + 2 + nonzeros])
        positions.append(np.arange(pixel, pixel + nonzeros))
        pixel += nonzeros
        i += 2 + nonzeros
    if deltas:
        zigzag = np.concatenate(deltas)
        delta = (zigzag >> 1) ^ -(zigzag & 1)
        out[np.concatenate(positions)] = np.cumsum(delta)
    return (out & 0xFFFF).astype(np.uint16)


def encode_rvl(pixels: npt.NDArray[np.uint16]) -> bytes:
    """(N,) uint16 -> RVL words (reference encoder; pure Python, for tests and small images)."""
    # values as C `short`, so deltas (and the stream) are those of the reference implementation
    flat = np.asarray(pixels, dtype=np.uint16).reshape(-1).view(np.int16).astype(np.int64)
    words: list[int] = []
    state = {"word": 0, "count": 0}

    def put(value: int) -> None:
        while True:
            nibble = value & 0x7
            value >>= 3
            if value:
                nibble |= 0x8
            state["word"] = ((state["word"] << 4) | nibble) & 0xFFFFFFFF
            state["count"] += 1
            if state["count"] == 8:
                words.append(state["word"])
                state["word"] = state["count"] = 0
            if not value:
                return

    n = flat.size
    i = 0
    previous = 0
    while i < n:
        j = i
        while j < n and flat[j] == 0:
            j += 1
        put(j - i)
        k = j
        while k < n and flat[k] != 0:
            k += 1
        put(k - j)
        for v in flat[j:k].tolist():
            delta = v - previous
            put((delta << 1) ^ (delta >> 63))
            previous = v
        i = k
    if state["count"]:
        words.append((state["word"] << (4 * (8 - state["count"]))) & 0xFFFFFFFF)
    return np.asarray(words, dtype="<u4").tobytes()
