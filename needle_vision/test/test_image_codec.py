"""sensor_msgs/Image fields <-> numpy (no cv_bridge)."""
import cv2
import numpy as np
import pytest

from needle_vision.streams.image_codec import (ImageFormatError, gray_to_encoding, image_fields, image_message_to_gray,
                                               image_to_array, image_to_gray, read_gray_bmp)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8", "rgb8"])
def test_round_trip(encoding):
    gray = np.random.default_rng(0).uniform(0, 255, (7, 5))
    array = gray_to_encoding(gray, encoding)
    fields = image_fields(array, encoding)
    np.testing.assert_array_equal(image_to_array(**fields), array)
    expected = np.clip(np.rint(gray * 257), 0, 65535) if encoding == "mono16" else np.rint(gray)
    np.testing.assert_allclose(image_message_to_gray(fields), expected, atol=1)  # colour -> grey rounds


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
