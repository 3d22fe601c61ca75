"""`sensor_msgs/Image` and `sensor_msgs/CompressedImage` <-> numpy, for colour and depth.

Messages are duck-typed: anything with the message's field names works (rosbags dataclasses and
rclpy messages alike). Decoding returns the project's two boundary types:

- colour: (H, W, 3) uint8, RGB order, from rgb8, bgr8, rgba8, bgra8, mono8 (and 8UC1/8UC3/8UC4
  read as cv_bridge does, plus yuv422 variants);
- depth: (H, W) float32 metres, 0.0 where there is no reading (NaN, inf, zero or negative input),
  from 16UC1 / mono16 millimetres and 32FC1 metres.

`step` padding and `is_bigendian` are honoured. CompressedImage colour is any format OpenCV decodes
(JPEG, PNG); compressed depth: `decode_compressed_depth`. The inverse direction (`*_fields`, `encode_*`) returns field values for writers.
"""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import BagError

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]

# encoding -> (channels, numpy dtype of one channel)
_COLOUR_LAYOUT: dict[str, tuple[int, str]] = {
    "rgb8": (3, "u1"),
    "bgr8": (3, "u1"),
    "8UC3": (3, "u1"),
    "rgba8": (4, "u1"),
    "bgra8": (4, "u1"),
    "8UC4": (4, "u1"),
    "mono8": (1, "u1"),
    "8UC1": (1, "u1"),
    "yuv422": (2, "u1"),
    "uyvy": (2, "u1"),
    "yuv422_yuy2": (2, "u1"),
    "yuyv": (2, "u1"),
}
_DEPTH_LAYOUT: dict[str, tuple[str, float]] = {  # encoding -> (dtype, metres per unit)
    "16UC1": ("u2", 1e-3),
    "mono16": ("u2", 1e-3),
    "32FC1": ("f4", 1.0),
}
COLOUR_ENCODINGS = tuple(_COLOUR_LAYOUT)
DEPTH_ENCODINGS = tuple(_DEPTH_LAYOUT)

COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")  # format, depthQuantA, depthQuantB (12 bytes)


def _pixels(msg: Any, channels: int, dtype: str, topic: str) -> np.ndarray:
    """(H, W, C) or (H, W) view of `msg.data`, honouring step padding and byte order."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    row_bytes = w * channels * itemsize
    if h <= 0 or w <= 0:
        raise BagError(f"{topic}: image has size {w}x{h}, expected a positive width and height")
    if step < row_bytes:
        raise BagError(
            f"{topic}: image step {step} is smaller than width*channels*bytes = {row_bytes} "
            f"({msg.encoding}, {w} px wide)"
        )
    buf = np.frombuffer(_as_bytes(msg.data), dtype=np.uint8)
    if buf.size < step * h:
        raise BagError(
            f"{topic}: image data has {buf.size} bytes, expected step*height = {step}*{h} = {step * h}"
        )
    rows = buf[: step * h].reshape(h, step)[:, :row_bytes]
    order = ">" if int(msg.is_bigendian) and itemsize > 1 else "<"
    arr = np.ascontiguousarray(rows).view(np.dtype(order + dtype)).reshape(h, w, channels)
    return arr[:, :, 0] if channels == 1 else arr


def _as_bytes(data: Any) -> bytes | memoryview | np.ndarray:
    if isinstance(data, (bytes, bytearray, memoryview, np.ndarray)):
        return data
    return bytes(data)  # rclpy array.array or list


def decode_rgb(msg: Any, topic: str = "image") -> U8:
    """`sensor_msgs/Image` -> (H, W, 3) uint8 RGB."""
    enc = str(msg.encoding)
    if enc not in _COLOUR_LAYOUT:
        raise BagError(
            f"{topic}: unsupported colour encoding '{enc}'; expected one of {', '.join(COLOUR_ENCODINGS)}"
        )
    channels, dtype = _COLOUR_LAYOUT[enc]
    px = _pixels(msg, channels, dtype, topic)
    if enc == "rgb8":
        return np.ascontiguousarray(px)
    if enc in ("bgr8", "8UC3"):
        return np.ascontiguousarray(px[:, :, ::-1])
    if enc == "rgba8":
        return np.ascontiguousarray(px[:, :, :3])
    if enc in ("bgra8", "8UC4"):
        return np.ascontiguousarray(px[:, :, 2::-1])
    if enc in ("mono8", "8UC1"):
        return np.repeat(px[:, :, None], 3, axis=2)
    code = cv2.COLOR_YUV2RGB_UYVY if enc in ("yuv422", "uyvy") else cv2.COLOR_YUV2RGB_YUY2
    return np.ascontiguousarray(cv2.cvtColor(np.ascontiguousarray(px), code))


def decode_depth(msg: Any, topic: str = "depth") -> F32:
    """`sensor_msgs/Image` -> (H, W) float32 metres, 0.0 = no reading."""
    enc = str(msg.encoding)
    if enc not in _DEPTH_LAYOUT:
        raise BagError(
            f"{topic}: unsupported depth encoding '{enc}'; expected one of {', '.join(DEPTH_ENCODINGS)}"
        )
    dtype, scale = _DEPTH_LAYOUT[enc]
    px = _pixels(msg, 1, dtype, topic)
    return clean_depth(px.astype(np.float32) * np.float32(scale) if scale != 1.0 else px)


def clean_depth(depth: np.ndarray) -> F32:
    """Float32 copy with NaN, inf and values <= 0 set to 0.0."""
    out = np.array(depth, dtype=np.float32, copy=True)
    out[~np.isfinite(out) | (out <= 0.0)] = 0.0
    return out


# -- CompressedImage -----------------------------------------------------------------------------
def _imdecode(data: Any, topic: str, what: str) -> np.ndarray:
    buf = np.frombuffer(_as_bytes(data), dtype=np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise BagError(f"{topic}: {what} data ({buf.size} bytes) cannot be decoded")
    return img


def decode_compressed_rgb(msg: Any, topic: str = "image") -> U8:
    """`sensor_msgs/CompressedImage` (JPEG, PNG, anything OpenCV reads) -> (H, W, 3) uint8 RGB."""
    fmt = str(msg.format)
    if "compressedDepth" in fmt:
        raise BagError(f"{topic}: format '{fmt}' is a depth image, expected a colour image")
    img = _imdecode(msg.data, topic, f"compressed colour image (format '{fmt}')")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise BagError(f"{topic}: compressed colour image decodes to {img.dtype}, expected 8-bit")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if _stored_as_rgb(fmt):
        return np.ascontiguousarray(img[:, :, :3])
    code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return np.ascontiguousarray(cv2.cvtColor(img, code))


def _stored_as_rgb(fmt: str) -> bool:
    """image_transport's rule: with 'ENC; jpeg compressed TARGET', OpenCV's decoded channel order is
    BGR when TARGET is bgr8/bgra8 and RGB otherwise; a bare 'jpeg' / 'png' means BGR."""
    if ";" not in fmt:
        return False
    return "compressed rgb" in fmt.split(";", 1)[1]


def decode_compressed_depth(msg: Any, topic: str = "depth") -> F32:
    """`sensor_msgs/CompressedImage` depth -> (H, W) float32 metres, 0.0 = no reading.

    Accepts `compressedDepth` (PNG payload; RVL is not supported) and plain 16-bit PNG in
    millimetres; a decoded float image is taken as metres. image_transport's `compressedDepth` format is a
    12-byte header {int32 format, float32 depthQuantA, float32 depthQuantB} followed by a PNG, holding
    millimetres for 16UC1 and quantised inverse depth for 32FC1 (depth = depthQuantA / (value - depthQuantB),
    value 0 = no reading).
    """
    fmt = str(msg.format)
    if "compressedDepth" in fmt:
        return _decode_compressed_depth_transport(msg, fmt, topic)
    img = _imdecode(msg.data, topic, f"compressed depth image (format '{fmt}')")
    if img.ndim != 2:
        raise BagError(f"{topic}: compressed depth (format '{fmt}') has {img.shape[2]} channels, expected 1")
    if img.dtype == np.uint16:
        return clean_depth(img.astype(np.float32) * np.float32(1e-3))
    if img.dtype == np.float32:
        return clean_depth(img)
    raise BagError(
        f"{topic}: compressed depth (format '{fmt}') decodes to {img.dtype}, "
        "expected a 16-bit PNG in millimetres"
    )


def _decode_compressed_depth_transport(msg: Any, fmt: str, topic: str) -> F32:
    encoding = fmt.split(";", 1)[0].strip()
    codec = fmt.split("compressedDepth", 1)[1].strip() or "png"
    if codec not in ("png", "rvl"):
        raise BagError(f"{topic}: compressedDepth codec '{codec}' (format '{fmt}') unsupported; expected png or rvl")
    data = bytes(_as_bytes(msg.data))
    if len(data) <= COMPRESSED_DEPTH_HEADER.size:
        raise BagError(f"{topic}: compressedDepth data has {len(data)} bytes, shorter than its 12-byte header")
    _, quant_a, quant_b = COMPRESSED_DEPTH_HEADER.unpack_from(data, 0)
    payload = data[COMPRESSED_DEPTH_HEADER.size :]
    if codec == "rvl":
        img = _decode_rvl_payload(payload, topic, fmt)
    else:
        img = _imdecode(payload, topic, f"compressedDepth PNG (format '{fmt}')")
    if img.dtype != np.uint16 or img.ndim != 2:
        raise BagError(f"{topic}: compressedDepth PNG is {img.dtype} x{img.ndim}D, expected 16-bit single channel")
    if encoding in ("16UC1", "mono16"):
        return clean_depth(img.astype(np.float32) * np.float32(1e-3))
    if encoding == "32FC1":
        value = img.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.float32(quant_a) / (value - np.float32(quant_b))
        depth[img == 0] = 0.0
        return clean_depth(depth)
    raise BagError(f"{topic}: compressedDepth encoding '{encoding}' unsupported; expected 16UC1 or 32FC1")


def _decode_rvl_payload(payload: bytes, topic: str, fmt: str) -> npt.NDArray[np.uint16]:
    """uint32 cols, uint32 rows, then the RVL stream (image_transport's layout)."""
    from changing_slam_ros.io.rvl_codec import decode_rvl

    if len(payload) < 8:
        raise BagError(f"{topic}: compressedDepth rvl data has no size header (format '{fmt}')")
    cols, rows = struct.unpack_from("<II", payload, 0)
    if rows == 0 or cols == 0 or rows * cols > 5 * len(payload) + 64:  # RVL compresses at most ~4x
        raise BagError(f"{topic}: compressedDepth rvl reports size {cols}x{rows} for {len(payload)} bytes")
    try:
        return decode_rvl(payload[8:], rows * cols).reshape(rows, cols)
    except ValueError as err:
        raise BagError(f"{topic}: compressedDepth rvl data is corrupt ({err})") from err


def decode_any_rgb(msg: Any, topic: str = "image") -> U8:
    """Image or CompressedImage colour (told apart by the `format` field)."""
    return decode_compressed_rgb(msg, topic) if hasattr(msg, "format") else decode_rgb(msg, topic)


def decode_any_depth(msg: Any, topic: str = "depth") -> F32:
    """Image or CompressedImage depth (told apart by the `format` field)."""
    return decode_compressed_depth(msg, topic) if hasattr(msg, "format") else decode_depth(msg, topic)


# -- numpy -> message field values -----------------------------------------------------------------
def rgb_image_fields(rgb: U8, encoding: str = "rgb8") -> dict[str, Any]:
    """(H, W, 3) uint8 RGB -> Image fields {height, width, encoding, is_bigendian, step, data}."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
    if encoding == "rgb8":
        px = rgb
    elif encoding == "bgr8":
        px = rgb[:, :, ::-1]
    else:
        raise ValueError(f"cannot encode colour as '{encoding}'; use rgb8 or bgr8")
    h, w = rgb.shape[:2]
    data = np.ascontiguousarray(px).reshape(-1)
    return {"height": h, "width": w, "encoding": encoding, "is_bigendian": 0, "step": w * 3, "data": data}


def depth_image_fields(depth_m: F32, encoding: str = "32FC1") -> dict[str, Any]:
    """(H, W) metres -> Image fields; 32FC1 keeps metres, 16UC1 rounds to millimetres (max 65.535 m)."""
    depth = clean_depth(np.asarray(depth_m))
    if depth.ndim != 2:
        raise ValueError(f"expected (H, W) depth, got shape {depth.shape}")
    h, w = depth.shape
    if encoding == "32FC1":
        data = depth.astype("<f4").view(np.uint8).reshape(-1)
        step = w * 4
    elif encoding in ("16UC1", "mono16"):
        data = depth_to_mm(depth).astype("<u2").view(np.uint8).reshape(-1)
        step = w * 2
    else:
        raise ValueError(f"cannot encode depth as '{encoding}'; use 32FC1 or 16UC1")
    return {"height": h, "width": w, "encoding": encoding, "is_bigendian": 0, "step": step, "data": data}


def depth_to_mm(depth_m: F32) -> npt.NDArray[np.uint16]:
    """Metres -> uint16 millimetres, rounded; readings beyond 65.535 m become 0 (no reading)."""
    mm = np.rint(clean_depth(depth_m) * np.float32(1000.0))
    mm[mm > 65535] = 0
    out: npt.NDArray[np.uint16] = mm.astype(np.uint16)
    return out


def encode_compressed_rgb(rgb: U8, fmt: str = "jpeg", quality: int = 95) -> tuple[str, U8]:
    """(H, W, 3) uint8 RGB -> (CompressedImage.format, data); fmt 'jpeg' or 'png'."""
    bgr = np.ascontiguousarray(np.asarray(rgb)[:, :, ::-1])
    if fmt == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    elif fmt == "png":
        ok, buf = cv2.imencode(".png", bgr)
    else:
        raise ValueError(f"cannot compress colour as '{fmt}'; use jpeg or png")
    if not ok:
        raise ValueError(f"OpenCV failed to encode a {rgb.shape} image as {fmt}")
    return f"rgb8; {fmt} compressed bgr8", buf.reshape(-1)


def encode_png_depth(depth_m: F32) -> tuple[str, U8]:
    """(H, W) metres -> (format, data): a 16-bit PNG in millimetres (what Foxglove shows)."""
    ok, buf = cv2.imencode(".png", depth_to_mm(depth_m))
    if not ok:
        raise ValueError("OpenCV failed to encode depth as 16-bit PNG")
    return "16UC1; png compressed", buf.reshape(-1)


def encode_compressed_depth(
    depth_m: F32,
    encoding: str = "16UC1",
    depth_max_m: float = 10.0,
    depth_quantization: float = 100.0,
    codec: str = "png",
) -> tuple[str, U8]:
    """(H, W) metres -> image_transport `compressedDepth` (format, data), PNG codec.

    16UC1 stores millimetres; 32FC1 stores quantised inverse depth with image_transport's defaults
    (depthQuantA = q (q + 1), depthQuantB = 1 - depthQuantA / depth_max).
    """
    depth = clean_depth(depth_m)
    if encoding == "16UC1":
        header = COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0)
        img = depth_to_mm(depth)
        img[img > int(depth_max_m * 1000.0)] = 0
    elif encoding == "32FC1":
        quant_a = np.float32(depth_quantization * (depth_quantization + 1.0))
        quant_b = np.float32(1.0 - quant_a / np.float32(depth_max_m))
        header = COMPRESSED_DEPTH_HEADER.pack(0, float(quant_a), float(quant_b))
        valid = (depth > 0) & (depth < depth_max_m)
        with np.errstate(divide="ignore"):
            inv = np.where(valid, quant_a / np.where(valid, depth, 1.0) + quant_b, 0.0)
        img = np.clip(inv, 0, 65535).astype(np.uint16)  # truncation, as the C++ cast does
    else:
        raise ValueError(f"compressedDepth encodes 16UC1 or 32FC1, not '{encoding}'")
    if codec == "rvl":
        from changing_slam_ros.io.rvl_codec import encode_rvl

        body = struct.pack("<II", img.shape[1], img.shape[0]) + encode_rvl(img)
    elif codec == "png":
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise ValueError("OpenCV failed to encode the compressedDepth PNG")
        body = buf.tobytes()
    else:
        raise ValueError(f"compressedDepth codec '{codec}' unknown; use png or rvl")
    payload = np.frombuffer(header + body, dtype=np.uint8)
    return f"{encoding}; compressedDepth {codec}", payload
