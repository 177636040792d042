"""sensor_msgs/Image fields <-> numpy (no cv_bridge); sensor_msgs/CompressedImage decoded and encoded."""
import array

import cv2
import numpy as np
import pytest

from needle_vision.streams.image_codec import (ImageFormatError, compress_image, compressed_to_gray, gray_to_encoding,
                                               image_fields, image_to_array, image_to_gray, read_gray_bmp)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8", "rgb8"])
def test_round_trip(encoding):
    gray = np.random.default_rng(0).uniform(0, 255, (7, 5))
    array = gray_to_encoding(gray, encoding)
    fields = image_fields(array, encoding)
    np.testing.assert_array_equal(image_to_array(**fields), array)
    expected = np.clip(np.rint(gray * 257), 0, 65535) if encoding == "mono16" else np.rint(gray)
    np.testing.assert_allclose(image_to_gray(**fields), expected, atol=1)  # colour -> grey rounds


def test_row_padding_and_big_endian_are_honoured():
    values = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    padded = np.zeros((3, 6), np.uint16)
    padded[:, :4] = values
    data = padded.astype(">u2").tobytes()
    np.testing.assert_array_equal(image_to_gray(3, 4, "mono16", 12, data, is_bigendian=True), values)


def test_colour_conversion_weights_channels_by_their_order():
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 2] = 200  # red in bgr8
    as_bgr = image_to_gray(2, 2, "bgr8", 6, red.tobytes())
    as_rgb = image_to_gray(2, 2, "rgb8", 6, red.tobytes())  # the same bytes read as rgb: blue
    assert as_bgr[0, 0] == pytest.approx(0.299 * 200, abs=1) and as_rgb[0, 0] == pytest.approx(0.114 * 200, abs=1)


@pytest.mark.parametrize("arguments, message", [
    ((2, 2, "bayer_rggb8", 2, bytes(4)), "unsupported image encoding 'bayer_rggb8'"),
    ((2, 2, "mono8", 1, bytes(4)), "step 1 is smaller"),
    ((2, 2, "mono16", 4, bytes(6)), "expected 8"),
])
def test_unusable_images_are_explained(arguments, message):
    with pytest.raises(ImageFormatError, match=message):
        image_to_gray(*arguments)


def test_array_must_match_encoding():
    with pytest.raises(ImageFormatError, match="does not match"):
        image_fields(np.zeros((2, 2), np.uint16), "mono8")


@pytest.mark.parametrize("width", [1, 3, 6, 641])
def test_grey_bmp_is_read_without_decoding(width):
    pixels = np.random.default_rng(width).integers(0, 256, (5, width), dtype=np.uint8)
    data = bytearray(cv2.imencode(".bmp", pixels)[1].tobytes())  # bottom-up rows padded to 4 bytes
    image = read_gray_bmp(bytes(data))
    np.testing.assert_array_equal(image, pixels)
    assert image.flags.c_contiguous
    offset, stride = int.from_bytes(data[10:14], "little"), (width + 3) & ~3
    rows = [data[offset + row * stride:offset + (row + 1) * stride] for row in range(5)]
    top_down = data[:offset] + b"".join(rows[::-1])
    top_down[22:26] = (-5).to_bytes(4, "little", signed=True)
    np.testing.assert_array_equal(read_gray_bmp(bytes(top_down)), pixels)


def test_other_bmps_are_left_to_opencv():
    pixels = np.random.default_rng(0).integers(0, 256, (4, 8), dtype=np.uint8)
    data = bytearray(cv2.imencode(".bmp", pixels)[1].tobytes())
    tinted = data[:54 + 4 * 7] + b"\x00\x00\x08\x00" + data[54 + 4 * 8:]  # palette entry 7 is not grey
    for other in (cv2.imencode(".bmp", np.dstack([pixels] * 3))[1].tobytes(), bytes(tinted), bytes(data[:-3]),
                  cv2.imencode(".png", pixels)[1].tobytes()):
        assert read_gray_bmp(other) is None


# --- CompressedImage ----------------------------------------------------------------------------------------

def _scene(encoding: str) -> np.ndarray:
    """A smooth grey scene with a dark line (JPEG-friendly) in ``encoding``'s layout."""
    y, x = np.mgrid[0:60, 0:80]
    gray = 120 + 60 * np.sin(x / 9.0) * np.cos(y / 13.0)
    gray[28:32, 10:70] = 30.0
    return gray_to_encoding(gray, encoding)


@pytest.mark.parametrize("encoding, codec", [("mono8", "png"), ("mono16", "png"), ("bgr8", "png"), ("rgb8", "png"),
                                             ("mono8", "jpeg"), ("bgr8", "jpeg"), ("rgb8", "jpeg")])
def test_compressed_image_decodes_to_the_grey_of_the_raw_image(encoding, codec):
    pixels = _scene(encoding)
    raw = image_to_gray(**image_fields(pixels, encoding))  # the raw transport's grey: the reference
    image_format, data = compress_image(pixels, encoding, codec)
    target = "bgr8" if pixels.ndim == 3 else encoding
    assert image_format == f"{encoding}; {codec} compressed {target}"  # compressed_image_transport's format
    gray = compressed_to_gray(data, image_format)
    assert gray.dtype == raw.dtype and gray.shape == raw.shape
    if codec == "png":  # lossless
        np.testing.assert_array_equal(gray, raw)
    else:
        assert np.abs(gray.astype(float) - raw).mean() < 1.5


@pytest.mark.parametrize("image_format", ["bgr8; jpeg compressed bgr8", "rgb8; jpeg compressed bgr8", "jpeg", "JPEG",
                                          "8UC3; jpeg compressed bgr8", "", "unknown"])
def test_jpeg_formats_as_publishers_write_them(image_format):
    colour = np.dstack([np.full((40, 50), v, np.uint8) for v in (20, 120, 220)])  # BGR, as compressed stores colour
    data = cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 100])[1].tobytes()
    expected = 0.114 * 20 + 0.587 * 120 + 0.299 * 220  # BT.601 grey of the BGR pixel
    assert compressed_to_gray(data, image_format) == pytest.approx(np.full((40, 50), expected), abs=2)


@pytest.mark.parametrize("image_format", ["mono8; png compressed", "mono8; png compressed mono8", "png", " png ",
                                          "mono8"])
def test_png_formats_as_publishers_write_them(image_format):
    pixels = np.random.default_rng(1).integers(0, 256, (30, 40), dtype=np.uint8)
    data = cv2.imencode(".png", pixels)[1].tobytes()
    np.testing.assert_array_equal(compressed_to_gray(data, image_format), pixels)


def test_rclpy_style_arrays_are_read():
    pixels = np.random.default_rng(2).integers(0, 256, (10, 12), dtype=np.uint8)
    image_format, data = compress_image(pixels, "mono8", "png")
    # rclpy holds uint8[] as array.array('B')
    np.testing.assert_array_equal(compressed_to_gray(array.array("B", data), image_format), pixels)
    np.testing.assert_array_equal(compressed_to_gray(data, image_format), pixels)


@pytest.mark.parametrize("data", [b"", b"not an image at all", bytes(range(256)) * 40, "truncated png",
                                  "jpeg header only"])
def test_corrupt_compressed_data_is_a_format_error(data):
    pixels = np.random.default_rng(3).integers(0, 256, (60, 80), dtype=np.uint8)
    if data == "truncated png":
        data = cv2.imencode(".png", pixels)[1].tobytes()[:200]
    elif data == "jpeg header only":
        data = cv2.imencode(".jpg", pixels)[1].tobytes()[:100]
    with pytest.raises(ImageFormatError, match="cannot decode the compressed image"):
        compressed_to_gray(data, "mono8; png compressed mono8")


@pytest.mark.parametrize("image_format, message", [("16UC1; compressedDepth png", "compressedDepth"),
                                                   ("h264", "unsupported compression"),
                                                   ("bgr8; theora compressed bgr8", "unsupported compression"),
                                                   ("what is this", "unsupported compression")])
def test_formats_opencv_cannot_read_are_refused(image_format, message):
    data = cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes()
    with pytest.raises(ImageFormatError, match=message):
        compressed_to_gray(data, image_format)


def test_compress_image_refuses_what_compressed_image_transport_refuses():
    with pytest.raises(ImageFormatError, match="8-bit"):
        compress_image(np.zeros((4, 4), np.uint16), "mono16", "jpeg")
    with pytest.raises(ImageFormatError, match="does not match"):
        compress_image(np.zeros((4, 4), np.uint16), "mono8", "png")


