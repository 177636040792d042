"""sensor_msgs/Image fields <-> numpy (no cv_bridge)."""
import numpy as np
import pytest

from needle_vision.streams.image_codec import (ImageFormatError, gray_to_encoding, image_fields, image_message_to_gray,
                                               image_to_array, image_to_gray)


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
