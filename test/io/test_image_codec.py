"""Image / CompressedImage decoding and encoding on real TUM fr1 pixels."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.errors import BagError
from changing_slam_ros.io import image_codec as ic


@pytest.fixture(scope="module")
def fr1() -> tuple[np.ndarray, np.ndarray]:
    """First fr1_xyz colour frame (RGB) and its depth in metres, read with OpenCV."""
    root = require(FR1_XYZ_10)
    bgr = cv2.imread(str(root / "rgb/1305031102.175304.png"), cv2.IMREAD_UNCHANGED)
    raw = cv2.imread(str(root / "depth/1305031102.194330.png"), cv2.IMREAD_UNCHANGED)
    assert bgr.shape == (480, 640, 3) and raw.dtype == np.uint16
    return bgr[:, :, ::-1].copy(), raw.astype(np.float32) / 5000.0


def _msg(**fields: object) -> SimpleNamespace:
    return SimpleNamespace(**fields)


def _image(px: np.ndarray, encoding: str, *, pad: int = 0, bigendian: bool = False) -> SimpleNamespace:
    """Image message from an array, with `pad` extra bytes at the end of every row."""
    h, w = px.shape[:2]
    dt = px.dtype.newbyteorder(">" if bigendian else "<")
    rows = px.astype(dt).reshape(h, -1).view(np.uint8)
    padded = np.zeros((h, rows.shape[1] + pad), np.uint8)
    padded[:, : rows.shape[1]] = rows
    return _msg(height=h, width=w, encoding=encoding, is_bigendian=int(bigendian),
                step=padded.shape[1], data=padded.reshape(-1))  # fmt: skip


@pytest.mark.parametrize("pad", [0, 7])
def test_every_colour_encoding_decodes_to_the_same_rgb(fr1: tuple[np.ndarray, np.ndarray], pad: int) -> None:
    rgb, _ = fr1
    cases = {
        "rgb8": rgb,
        "bgr8": rgb[:, :, ::-1],
        "8UC3": rgb[:, :, ::-1],
        "rgba8": np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)]),
        "bgra8": np.dstack([rgb[:, :, ::-1], np.full(rgb.shape[:2], 9, np.uint8)]),
    }
    for enc, px in cases.items():
        out = ic.decode_rgb(_image(np.ascontiguousarray(px), enc, pad=pad), "/cam")
        assert out.dtype == np.uint8 and out.shape == (480, 640, 3), enc
        np.testing.assert_array_equal(out, rgb, err_msg=enc)
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    mono = ic.decode_rgb(_image(gray, "mono8", pad=pad))
    np.testing.assert_array_equal(mono, np.dstack([gray] * 3))


def test_yuv422_uses_bt601_video_range() -> None:
    # ROS yuv422 is UYVY. BT.601 video-range reference colours: white Y=235, black Y=16,
    # red (Y, Cb, Cr) = (81, 90, 240), blue = (41, 240, 110); U/V shared by each pixel pair.
    pairs = [(235, 128, 128), (16, 128, 128), (81, 90, 240), (41, 240, 110)]
    uyvy = np.array([[[u, y], [v, y]] for y, u, v in pairs], np.uint8).reshape(1, 8, 2)
    out = ic.decode_rgb(_image(np.repeat(uyvy, 2, axis=0), "yuv422")).astype(int)
    expected = np.repeat([[255, 255, 255], [0, 0, 0], [255, 0, 0], [0, 0, 255]], 2, axis=0)
    assert np.abs(out[0] - expected).max() <= 3
    yuyv = uyvy[:, :, ::-1].copy()  # YUY2 swaps the byte order inside each pixel
    np.testing.assert_array_equal(ic.decode_rgb(_image(np.repeat(yuyv, 2, axis=0), "yuyv")), out)


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("pad", [0, 6])
def test_depth_16uc1_is_millimetres_and_32fc1_metres(
    fr1: tuple[np.ndarray, np.ndarray], bigendian: bool, pad: int
) -> None:
    _, depth = fr1
    mm = np.rint(depth * 1000).astype(np.uint16)
    for enc in ("16UC1", "mono16"):
        out = ic.decode_depth(_image(mm, enc, pad=pad, bigendian=bigendian), "/depth")
        assert out.dtype == np.float32
        np.testing.assert_allclose(out, mm / 1000.0, rtol=0, atol=1e-6)
    out = ic.decode_depth(_image(depth, "32FC1", pad=pad, bigendian=bigendian))
    np.testing.assert_array_equal(out, depth)
    # real values: fr1 desk scene at 0.5 .. 3 m, about 80 % valid pixels
    valid = out > 0
    assert 0.6 < valid.mean() < 1.0
    assert 0.4 < float(out[valid].min()) and float(out[valid].max()) < 5.0


def test_invalid_depth_values_become_zero() -> None:
    d = np.array([[np.nan, np.inf, -np.inf, -1.0, 0.0, 1.5]], np.float32)
    out = ic.decode_depth(_image(d, "32FC1"))
    np.testing.assert_array_equal(out, [[0, 0, 0, 0, 0, 1.5]])


def test_unknown_encodings_name_the_topic_and_encoding() -> None:
    img = _image(np.zeros((2, 2, 3), np.uint8), "bayer_rggb8")
    with pytest.raises(BagError, match=r"/camera/x: unsupported colour encoding 'bayer_rggb8'"):
        ic.decode_rgb(img, "/camera/x")
    with pytest.raises(BagError, match=r"/d: unsupported depth encoding 'rgb8'"):
        ic.decode_depth(_image(np.zeros((2, 2, 3), np.uint8), "rgb8"), "/d")


def test_short_data_and_bad_step_are_reported() -> None:
    img = _image(np.zeros((4, 5, 3), np.uint8), "rgb8")
    img.data = img.data[:-1]
    with pytest.raises(BagError, match=r"/c: image data has 59 bytes, expected step\*height"):
        ic.decode_rgb(img, "/c")
    img = _image(np.zeros((4, 5), np.uint16), "16UC1")
    img.step = 9
    with pytest.raises(BagError, match=r"/d: image step 9 is smaller than"):
        ic.decode_depth(img, "/d")


def test_image_fields_round_trip(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    rgb, depth = fr1
    for enc in ("rgb8", "bgr8"):
        np.testing.assert_array_equal(ic.decode_rgb(_msg(**ic.rgb_image_fields(rgb, enc))), rgb)
    np.testing.assert_array_equal(ic.decode_depth(_msg(**ic.depth_image_fields(depth, "32FC1"))), depth)
    back = ic.decode_depth(_msg(**ic.depth_image_fields(depth, "16UC1")))
    assert np.abs(back - depth).max() <= 0.0005 + 1e-6  # millimetre rounding
    assert ((back > 0) == (depth > 0)).all()


def test_compressed_colour_png_is_lossless_and_jpeg_close(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    rgb, _ = fr1
    fmt, data = ic.encode_compressed_rgb(rgb, "png")
    np.testing.assert_array_equal(ic.decode_compressed_rgb(_msg(format=fmt, data=data)), rgb)
    fmt, data = ic.encode_compressed_rgb(rgb, "jpeg", quality=95)
    assert fmt == "rgb8; jpeg compressed bgr8"
    out = ic.decode_any_rgb(_msg(format=fmt, data=data))
    err = np.abs(out.astype(int) - rgb.astype(int)).mean()
    swapped = np.abs(out[:, :, ::-1].astype(int) - rgb.astype(int)).mean()
    # measured on this frame: 3.18 grey levels (Kinect noise compresses poorly), 11.2 if R/B swapped
    assert err < 4.0 < swapped and len(data) < rgb.size / 4
    # a JPEG written by cv2 from the source file decodes to the same pixels cv2 reads back
    ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1])
    ref = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    np.testing.assert_array_equal(ic.decode_compressed_rgb(_msg(format="jpeg", data=buf.reshape(-1))), ref)


def test_compressed_colour_channel_order_follows_the_format_string(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    rgb, _ = fr1
    ok, bgr_png = cv2.imencode(".png", rgb[:, :, ::-1])  # what compressed_image_transport stores for bgr8 targets
    ok, rgb_png = cv2.imencode(".png", rgb)  # an encoder that stored RGB bytes ("... compressed rgb8")
    for fmt in ("png", "rgb8; png compressed bgr8", "bgr8; png compressed bgr8"):
        np.testing.assert_array_equal(ic.decode_compressed_rgb(_msg(format=fmt, data=bgr_png)), rgb, err_msg=fmt)
    np.testing.assert_array_equal(ic.decode_compressed_rgb(_msg(format="rgb8; png compressed rgb8", data=rgb_png)), rgb)


def test_png_depth_is_millimetres(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    _, depth = fr1
    fmt, data = ic.encode_png_depth(depth)
    out = ic.decode_any_depth(_msg(format=fmt, data=data))
    np.testing.assert_allclose(out, np.rint(depth * 1000) / 1000, atol=1e-6)


def test_compressed_depth_16uc1_is_exact_millimetres(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    _, depth = fr1
    fmt, data = ic.encode_compressed_depth(depth, "16UC1")
    assert fmt == "16UC1; compressedDepth png"
    out = ic.decode_compressed_depth(_msg(format=fmt, data=data))
    np.testing.assert_allclose(out, np.rint(depth * 1000) / 1000, atol=1e-6)
    # the older format string without codec means png
    out_old = ic.decode_compressed_depth(_msg(format="16UC1; compressedDepth", data=data))
    np.testing.assert_array_equal(out_old, out)


def test_compressed_depth_32fc1_inverts_the_quantisation(fr1: tuple[np.ndarray, np.ndarray]) -> None:
    _, depth = fr1
    fmt, data = ic.encode_compressed_depth(depth, "32FC1")
    header = bytes(data[:12])
    kind, qa, qb = ic.COMPRESSED_DEPTH_HEADER.unpack(header)
    assert (kind, qa, qb) == (0, 10100.0, -1009.0)  # image_transport defaults: q=100, max 10 m
    out = ic.decode_compressed_depth(_msg(format=fmt, data=data))
    valid = depth > 0
    assert ((out > 0) == valid).all()
    # quantisation step of inverse depth: error <= d^2 / qa, about 0.9 mm at 3 m
    err = np.abs(out[valid] - depth[valid])
    assert (err <= depth[valid] ** 2 / 10100.0 + 1e-5).all()
    assert float(err.max()) < 0.002


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_compressed_depth_rvl_matches_png(fr1: tuple[np.ndarray, np.ndarray], encoding: str) -> None:
    _, depth = fr1
    fmt_png, png = ic.encode_compressed_depth(depth, encoding, codec="png")
    fmt_rvl, rvl = ic.encode_compressed_depth(depth, encoding, codec="rvl")
    assert fmt_rvl == f"{encoding}; compressedDepth rvl" and len(rvl) < depth.size * 2 / 3
    out = ic.decode_compressed_depth(_msg(format=fmt_rvl, data=rvl))
    np.testing.assert_array_equal(out, ic.decode_compressed_depth(_msg(format=fmt_png, data=png)))
    cut = _msg(format=fmt_rvl, data=rvl[: len(rvl) // 2])
    with pytest.raises(BagError, match=r"/d: compressedDepth rvl data is corrupt \(RVL stream ends after"):
        ic.decode_compressed_depth(cut, "/d")


def test_rvl_stream_layout_on_a_hand_worked_example() -> None:
    from changing_slam_ros.io.rvl_codec import decode_rvl, encode_rvl

    # pixels 0 0 5 5: values 2 (zeros), 2 (nonzeros), zigzag(5)=10, zigzag(0)=0
    # nibbles: 2 | 2 | 10 = 0b010 + continue -> 0xA, then 0b001 -> 0x1 | 0  => 0x2, 0x2, 0xA, 0x1, 0x0
    # packed from the high end of one little-endian word, padded with zero nibbles: 0x22A10000
    words = np.array([0x22A10000], dtype="<u4").tobytes()
    assert encode_rvl(np.array([0, 0, 5, 5], np.uint16)) == words
    np.testing.assert_array_equal(decode_rvl(words, 4), [0, 0, 5, 5])


def test_compressed_depth_errors_are_named() -> None:
    with pytest.raises(BagError, match=r"/d: compressedDepth data has 5 bytes"):
        ic.decode_compressed_depth(_msg(format="16UC1; compressedDepth png", data=b"12345"), "/d")
    with pytest.raises(BagError, match=r"/d: compressedDepth codec 'zlib'"):
        ic.decode_compressed_depth(_msg(format="16UC1; compressedDepth zlib", data=b"0" * 40), "/d")
    with pytest.raises(BagError, match=r"/d: compressedDepth rvl reports size 808464432x808464432"):
        ic.decode_compressed_depth(_msg(format="16UC1; compressedDepth rvl", data=b"0" * 40), "/d")
    with pytest.raises(BagError, match=r"/d: compressed depth image \(format 'png'\) .*cannot be decoded"):
        ic.decode_compressed_depth(_msg(format="png", data=b"garbage!"), "/d")
    fmt, data = ic.encode_compressed_rgb(np.zeros((4, 4, 3), np.uint8), "png")
    with pytest.raises(BagError, match=r"/d: compressed depth .* has 3 channels"):
        ic.decode_compressed_depth(_msg(format=fmt, data=data), "/d")
    with pytest.raises(BagError, match=r"/c: format '16UC1; compressedDepth png' is a depth image"):
        ic.decode_compressed_rgb(_msg(format="16UC1; compressedDepth png", data=b""), "/c")
