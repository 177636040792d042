"""``sensor_msgs/Image`` fields <-> numpy arrays for mono8, mono16, bgr8 and rgb8 (no cv_bridge, no ROS).

The pipeline works on one grey channel: colour images are converted to grey. The node (its subscriptions are raw) and
the offline tools (a bag's records) read serialized ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` (CDR)
alike (:func:`deserialize_image`), without building message objects: the pixels stay a view into the serialized bytes.

``sensor_msgs/CompressedImage`` (image_transport's ``<image>/compressed`` topics) is decoded by
:func:`compressed_to_gray` with OpenCV. Its ``format`` follows
compressed_image_transport: ``"<encoding>; <jpeg|png> compressed <encoding of the compressed pixels>"`` (e.g.
``"bgr8; jpeg compressed bgr8"``, ``"mono16; png compressed mono16"``), or just ``"jpeg"``/``"png"`` as older
drivers write it; colour is stored as BGR in either. :func:`compress_image` writes the same formats.
"""
from __future__ import annotations

import re
import struct
import sys
from typing import Any, NamedTuple

import cv2
import numpy as np

from needle_common.cdr import aligned, cdr_string

#: encoding -> (dtype, channels)
ENCODINGS = {"mono8": (np.uint8, 1), "mono16": (np.uint16, 1), "bgr8": (np.uint8, 3), "rgb8": (np.uint8, 3)}


class ImageFormatError(ValueError):
    """An image whose encoding, size or buffer the pipeline cannot use; the message says why."""


def image_to_array(height: int, width: int, encoding: str, step: int, data: bytes | bytearray | np.ndarray,
                   is_bigendian: bool = False) -> np.ndarray:
    """The pixels as an ``(height, width)`` or ``(height, width, 3)`` array (a view where possible)."""
    if encoding not in ENCODINGS:
        raise ImageFormatError(f"unsupported image encoding '{encoding}' (supported: {', '.join(ENCODINGS)})")
    dtype, channels = ENCODINGS[encoding]
    itemsize = np.dtype(dtype).itemsize
    if height <= 0 or width <= 0 or step < width * channels * itemsize:
        raise ImageFormatError(f"{encoding} image {width}x{height}: step {step} is smaller than a row "
                               f"({width * channels * itemsize} bytes)")
    buffer = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    if buffer.size < step * height:
        raise ImageFormatError(f"{encoding} image {width}x{height}: data has {buffer.size} bytes, "
                               f"expected {step * height}")
    rows = buffer[:step * height].reshape(height, step)[:, :width * channels * itemsize]
    array = np.ascontiguousarray(rows).view(dtype) if itemsize > 1 else rows
    if itemsize > 1 and bool(is_bigendian) != (sys.byteorder == "big"):
        array = array.byteswap()
    return array.reshape(height, width, channels) if channels > 1 else array.reshape(height, width)


def image_to_gray(height: int, width: int, encoding: str, step: int, data: Any,
                  is_bigendian: bool = False) -> np.ndarray:
    """One grey channel (uint8 or uint16) of an image given by its ``sensor_msgs/Image`` fields."""
    array = image_to_array(height, width, encoding, step, data, is_bigendian)
    if array.ndim == 3:
        array = cv2.cvtColor(array, cv2.COLOR_BGR2GRAY if encoding == "bgr8" else cv2.COLOR_RGB2GRAY)
    return array


def gray_to_encoding(gray: np.ndarray, encoding: str) -> np.ndarray:
    """A grey image on the 8-bit scale (float allowed, clipped and rounded) in ``encoding``'s pixel layout
    (mono16 holds 257x the 8-bit value; colour encodings repeat the grey value in each channel)."""
    if encoding not in ENCODINGS:
        raise ImageFormatError(f"unsupported image encoding '{encoding}' (supported: {', '.join(ENCODINGS)})")
    if encoding == "mono16":
        return np.clip(np.rint(np.asarray(gray, dtype=np.float64) * 257.0), 0, 65535).astype(np.uint16)
    gray8 = np.clip(np.rint(gray), 0, 255).astype(np.uint8)
    return np.repeat(gray8[:, :, None], 3, axis=2) if ENCODINGS[encoding][1] == 3 else gray8


def image_fields(array: np.ndarray, encoding: str) -> dict[str, Any]:
    """``sensor_msgs/Image`` fields (without header) holding ``array`` in ``encoding`` (little-endian)."""
    dtype, channels = ENCODINGS.get(encoding, (None, None))
    if dtype is None or array.dtype != dtype or array.ndim != (3 if channels > 1 else 2) \
            or (channels > 1 and array.shape[2] != channels):
        raise ImageFormatError(f"array {array.shape} {array.dtype} does not match encoding '{encoding}'")
    array = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    return {"height": array.shape[0], "width": array.shape[1], "encoding": encoding, "is_bigendian": 0,
            "step": array.shape[1] * channels * array.itemsize, "data": array.tobytes()}


class SerializedImage(NamedTuple):
    """Header and payload of a serialized image message: stamp (sec, nanosec), frame_id, and either the
    ``sensor_msgs/Image`` fields (``compressed_format`` empty) or the ``CompressedImage`` format and bytes
    (``fields['data']``)."""

    sec: int
    nanosec: int
    frame_id: str
    fields: dict[str, Any]
    compressed_format: str = ""

    @property
    def stamp(self) -> float:
        """Header stamp [s]."""
        return self.sec + 1e-9 * self.nanosec

    def gray(self) -> np.ndarray:
        """One grey channel: a view of the serialized pixels for mono8/mono16, decoded for compressed images
        (OpenCV releases the GIL while decoding, so this runs well on worker threads)."""
        if not self.compressed_format:
            return image_to_gray(**self.fields)
        return compressed_to_gray(self.fields["data"], self.compressed_format)


_BMP_HEADER = struct.Struct("<2sI4xI")  # "BM", file size, pixel data offset
#: header size, width, height (< 0: top-down), planes, bits per pixel, compression, image size, resolution x, y,
#: palette entries (0: all 256)
_BMP_INFO = struct.Struct("<IiiHHIIiiI")


def read_gray_bmp(data: bytes) -> np.ndarray | None:
    """The pixels of an uncompressed 8-bit BMP with the grey palette (what ``cv2.imwrite`` writes for mono8) as
    a uint8 array, without decoding: the rows, flipped when stored bottom-up; None for any other BMP."""
    if len(data) < 54 + 1024:
        return None
    magic, _, offset = _BMP_HEADER.unpack_from(data, 0)
    header, width, height, _, bits, compression, _, _, _, colors = _BMP_INFO.unpack_from(data, 14)
    stride = (width + 3) & ~3
    if (magic != b"BM" or header < 40 or bits != 8 or compression != 0 or colors not in (0, 256) or width <= 0
            or height == 0 or offset < 14 + header + 1024 or len(data) < offset + stride * abs(height)):
        return None
    palette = np.frombuffer(data, np.uint8, 1024, 14 + header).reshape(256, 4)
    if not np.array_equal(palette[:, :3], np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)):
        return None
    rows = np.frombuffer(data, np.uint8, stride * abs(height), offset).reshape(abs(height), stride)[:, :width]
    return np.ascontiguousarray(rows[::-1] if height > 0 else rows)


def decoded_to_gray(image: np.ndarray) -> np.ndarray:
    """One grey channel of an image decoded by OpenCV (grey, BGR or BGRA)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return image


#: codecs OpenCV decodes, as named in a ``CompressedImage`` format -> file suffix for ``cv2.imencode``
CODECS = {"jpeg": ".jpg", "jpg": ".jpg", "png": ".png", "tiff": ".tif", "tif": ".tif", "bmp": ".bmp"}
#: "<encoding>; <codec> compressed <target>", "<codec>"
_FORMAT = re.compile(r"^(?:\w+\s*;\s*)?(?P<codec>\w+)(?:\s+compressed(?:\s+(?P<target>\w+))?)?$")


def compressed_codec(image_format: str) -> str | None:
    """The codec a ``CompressedImage`` format names (``"jpeg"``, ``"png"``, ...; None when it names none, e.g.
    empty: OpenCV then tells it from the data); ImageFormatError for a codec or transport OpenCV cannot read
    (compressedDepth, video codecs)."""
    text = image_format.strip()
    if "compresseddepth" in text.lower():
        raise ImageFormatError(f"compressed format '{image_format}': compressedDepth (depth images) is not supported")
    match = _FORMAT.match(text)
    if not text or text == "unknown" or (match and match["codec"].lower() in ENCODINGS and not match["target"]):
        return None  # no codec named (or only a pixel encoding): OpenCV recognises the data
    codec = match["codec"].lower() if match else ""
    if codec not in CODECS:
        raise ImageFormatError(f"compressed format '{image_format}': unsupported compression (supported: jpeg, png, "
                               "tiff, bmp)")
    return codec


def compressed_to_gray(data: Any, image_format: str) -> np.ndarray:
    """One grey channel (uint8, or uint16 for 16-bit PNG/TIFF) of a ``CompressedImage``'s data (any buffer: bytes,
    array.array, numpy); ImageFormatError when the format names something else than an image OpenCV reads, or the
    data do not decode."""
    compressed_codec(image_format)
    buffer = data.view(np.uint8) if isinstance(data, np.ndarray) else np.frombuffer(data, dtype=np.uint8)
    image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    if image is None or image.size == 0:
        raise ImageFormatError(f"cannot decode the compressed image ({buffer.size} bytes, format '{image_format}'): "
                               "corrupt or not an image")
    return decoded_to_gray(image)


def compress_image(array: np.ndarray, encoding: str, codec: str = "png", quality: int = 95) -> tuple[str, bytes]:
    """``(format, data)`` of a ``CompressedImage`` holding ``array`` (in ``encoding``'s layout) as
    compressed_image_transport writes it: colour as BGR, JPEG only for 8-bit images (``quality`` 1-100), PNG at
    compression level 1."""
    if encoding not in ENCODINGS or array.dtype != ENCODINGS[encoding][0]:
        raise ImageFormatError(f"array {array.shape} {array.dtype} does not match encoding '{encoding}'")
    if codec not in ("jpeg", "png"):
        raise ImageFormatError(f"codec '{codec}': jpeg or png")
    if codec == "jpeg" and array.dtype != np.uint8:
        raise ImageFormatError(f"JPEG holds 8-bit images only, not {encoding}")
    if encoding == "rgb8":
        array = cv2.cvtColor(array, cv2.COLOR_RGB2BGR)
    target = "bgr8" if array.ndim == 3 else encoding
    options = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if codec == "jpeg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
    ok, data = cv2.imencode(CODECS[codec], array, options)
    if not ok:
        raise ImageFormatError(f"OpenCV could not encode a {encoding} image as {codec}")
    return f"{encoding}; {codec} compressed {target}", data.tobytes()


def deserialize_image(data: bytes, compressed: bool) -> SerializedImage:
    """Read a CDR-serialized (little-endian XCDR1) ``sensor_msgs/Image`` or, with ``compressed``,
    ``sensor_msgs/CompressedImage``; the pixel bytes are not copied."""
    if len(data) < 12 or bytes(data[:2]) != b"\x00\x01":
        raise ImageFormatError("not a little-endian CDR image message")
    try:
        sec, nanosec = struct.unpack_from("<iI", data, 4)
        frame_id, offset = cdr_string(data, 12)
        if compressed:
            image_format, offset = cdr_string(data, offset)
            fields: dict[str, Any] = {}
        else:
            height, width = struct.unpack_from("<II", data, aligned(offset, 4))
            encoding, offset = cdr_string(data, aligned(offset, 4) + 8)
            (is_bigendian,) = struct.unpack_from("<B", data, offset)
            (step,) = struct.unpack_from("<I", data, aligned(offset + 1, 4))
            offset = aligned(offset + 1, 4) + 4
            fields = {"height": height, "width": width, "encoding": encoding, "step": step,
                      "is_bigendian": bool(is_bigendian)}
        (size,) = struct.unpack_from("<I", data, aligned(offset, 4))
    except (struct.error, ValueError) as error:
        raise ImageFormatError(f"truncated image message ({error})") from error
    offset = aligned(offset, 4) + 4
    if offset + size > len(data):
        raise ImageFormatError(f"image data of {size} bytes runs past the end of the message")
    fields["data"] = np.frombuffer(data, np.uint8, size, offset)
    if compressed:
        return SerializedImage(sec, nanosec, frame_id, fields, image_format or "unknown")
    return SerializedImage(sec, nanosec, frame_id, fields)
