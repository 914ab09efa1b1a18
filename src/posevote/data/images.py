"""Reading images into the one form every later stage expects.

Limits
------
An image may hold at most :data:`MAX_IMAGE_PIXELS` pixels (40 million by
default; the environment variable ``POSEVOTE_MAX_IMAGE_PIXELS`` or an
assignment to ``posevote.data.images.MAX_IMAGE_PIXELS`` changes it, as
PIL's decompression-bomb limit is changed; past twice Pillow's own limit,
``PIL.Image.MAX_IMAGE_PIXELS``, Pillow refuses too). A file's size is read
from its header and refused before the pixels are decoded. A file that decodes
with a warning (a truncated or corrupt JPEG, a PNG with a bad checksum) is
refused: its pixels are not what was photographed. Warnings about metadata
(colour profiles, unknown TIFF tags) are passed on to stderr, not refused.
"""

from __future__ import annotations

import io
import os
import re
import sys
import tempfile
import threading
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

_DEFAULT_LIMIT = 40_000_000


def _env_limit() -> tuple[int, str | None]:
    """The limit the environment sets, and what is wrong with it (reported when an image is
    read, not at import: ``posevote presets`` reads none)."""
    text = os.environ.get("POSEVOTE_MAX_IMAGE_PIXELS", "")
    if not text.strip():
        return _DEFAULT_LIMIT, None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and 1 <= value <= 1e12):
        return _DEFAULT_LIMIT, (f"the environment variable POSEVOTE_MAX_IMAGE_PIXELS must be a "
                                f"number of pixels from 1 to 1e12, got {text!r}")
    return int(value), None


#: The most pixels (height x width) an image may hold.
MAX_IMAGE_PIXELS: int
MAX_IMAGE_PIXELS, _ENV_ERROR = _env_limit()

#: Channel orders a colour array may be given in.
CHANNEL_ORDERS = ("rgb", "bgr")

# Floats a little outside [0, 1] come from interpolation overshoot and are
# clipped; further out the array is in other units (0..255) and is refused.
_FLOAT_SLACK = 0.05


def _check_size(name: str, height: int, width: int) -> None:
    limit = MAX_IMAGE_PIXELS
    if _ENV_ERROR is not None and limit == _DEFAULT_LIMIT:   # not set in code since
        raise ValueError(f"{name}: {_ENV_ERROR}")
    if height * width > limit:
        raise ValueError(
            f"{name}: the image is {width} x {height} = {height * width:,} pixels, over the limit "
            f"of {limit:,} (posevote.data.images.MAX_IMAGE_PIXELS, or the environment variable "
            "POSEVOTE_MAX_IMAGE_PIXELS); downscale it, or raise the limit")


def as_gray_float(image: NDArray, *, name: str = "image", channels: str = "rgb"
                  ) -> NDArray[np.float64]:
    """Convert an image array to grey levels in ``[0, 1]``.

    Accepts grey ``(H, W)``, colour ``(H, W, 3)`` and ``(H, W, 4)`` arrays of
    ``uint8``, ``uint16``, ``bool`` or float type; the fourth channel
    (alpha) is ignored. Floats must lie in ``[0, 1]``: values up to 0.05
    outside are clipped, further out the array is refused (a float image in
    0..255 must be divided by 255 first).

    Parameters
    ----------
    image : ndarray
        The image.
    name : str, optional
        How to name the image in error messages (a file name, an argument).
    channels : {"rgb", "bgr"}, optional
        The order of the colour channels: ``"bgr"`` for arrays from
        ``cv2.imread``.

    Returns
    -------
    ndarray, shape (H, W), float64

    Raises
    ------
    TypeError
        If ``image`` is not an array of a supported type.
    ValueError
        If it is empty, of an unsupported shape, over :data:`MAX_IMAGE_PIXELS`,
        holds NaN or infinity, or floats outside ``[0, 1]``.
    """
    if channels not in CHANNEL_ORDERS:
        raise ValueError(f"channels must be one of {', '.join(CHANNEL_ORDERS)}, got {channels!r}")
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name}: expected a numpy array, got {type(image).__name__}")
    if image.size == 0 or min(image.shape[:2], default=0) < 1:
        raise ValueError(f"{name}: the image is empty (shape {image.shape})")
    if image.ndim == 3 and image.shape[2] in (3, 4):
        rgb = image[..., :3]
    elif image.ndim == 3 and image.shape[2] == 1:
        rgb = image[..., 0]
    elif image.ndim == 2:
        rgb = image
    else:
        raise ValueError(
            f"{name}: expected a grey (H, W), RGB (H, W, 3) or RGBA (H, W, 4) image, "
            f"got shape {image.shape}"
        )
    _check_size(name, int(image.shape[0]), int(image.shape[1]))
    if rgb.dtype == np.uint8:
        scaled = rgb.astype(np.float64) / 255.0
    elif rgb.dtype == np.uint16:
        scaled = rgb.astype(np.float64) / 65535.0
    elif rgb.dtype == np.bool_:
        scaled = rgb.astype(np.float64)
    elif np.issubdtype(rgb.dtype, np.floating):
        scaled = rgb.astype(np.float64)
        # NaN and infinity carry into the extremes: two passes check everything.
        low, high = float(scaled.min()), float(scaled.max())
        if not (np.isfinite(low) and np.isfinite(high)):
            raise ValueError(f"{name}: the image holds NaN or infinite values")
        if low < -_FLOAT_SLACK or high > 1.0 + _FLOAT_SLACK:
            hint = " (divide a 0..255 image by 255)" if high > 1.0 + _FLOAT_SLACK else ""
            raise ValueError(f"{name}: float pixels must lie in [0, 1], these span "
                             f"[{low:g}, {high:g}]{hint}")
        if low < 0.0 or high > 1.0:
            scaled = np.clip(scaled, 0.0, 1.0)
    else:
        raise TypeError(f"{name}: unsupported pixel type {rgb.dtype}; use uint8, uint16 or float")
    if scaled.ndim == 3:
        luma = np.array([0.299, 0.587, 0.114])
        scaled = scaled @ (luma if channels == "rgb" else luma[::-1])
    return np.ascontiguousarray(scaled)


_ORIENTATION_TAG = 0x0112

#: How each EXIF orientation's stored pixels are turned upright (as a camera app shows them).
_UPRIGHT: dict[int, Any] = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: np.swapaxes(a, 0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: np.swapaxes(a, 0, 1)[::-1, ::-1],
    8: lambda a: np.rot90(a, 1),
}

_RADIANCE_SIZE = re.compile(rb"[-+]([YX]) +(\d+) +[-+]([YX]) +(\d+)")


def _other_header(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` from the header of the formats OpenCV reads and Pillow does not
    (Radiance HDR, PFM); None for any other."""
    if data.startswith(b"#?"):
        end = data.find(b"\n\n", 0, 1 << 16)
        line = data[end + 2:end + 2 + 64].split(b"\n", 1)[0] if end >= 0 else b""
        found = _RADIANCE_SIZE.match(line)
        if found is None:
            return None
        sizes = {found.group(1): int(found.group(2)), found.group(3): int(found.group(4))}
        return (sizes[b"Y"], sizes[b"X"]) if set(sizes) == {b"X", b"Y"} else None
    if data[:2] in (b"PF", b"Pf") and data[2:3].isspace():
        words = data[3:128].split()
        if len(words) >= 2 and words[0].isdigit() and words[1].isdigit():
            return int(words[1]), int(words[0])
    return None


def _check_file(path: Path, data: bytes) -> tuple[str | None, int]:
    """Refuse an image whose header is over the pixel limit, or that decodes with a warning.

    Pillow reads the header without decoding; of the formats it does not
    know, Radiance HDR and PFM headers are read here and any other is refused
    (its size cannot be known before OpenCV decodes it). A JPEG is not
    decoded here: libjpeg's warnings reach :func:`_decode`, and a cut one
    does not decode there. Returns Pillow's name of the format (None if it
    does not know it) and the EXIF orientation (1: as stored).
    """
    from PIL import Image, UnidentifiedImageError

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Pillow's own, higher limit warns at open; this module's limit decides.
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
                _check_size(str(path), height, width)
                if im.format != "JPEG":
                    im.load()
                orientation = im.getexif().get(_ORIENTATION_TAG, 1)
                return im.format, orientation if orientation in _UPRIGHT else 1
        except UnidentifiedImageError:
            shape = _other_header(data)
            if shape is None:
                raise ValueError(f"{path}: cannot decode this file as an image (unreadable, "
                                 "not an image, or a format whose size cannot be read before "
                                 "decoding it: Pillow's formats, Radiance HDR and PFM can)"
                                 ) from None
            _check_size(str(path), *shape)
            return None, 1
        except Image.DecompressionBombError as exc:
            raise ValueError(f"{path}: the image is over the pixel limit of "
                             f"{MAX_IMAGE_PIXELS:,} and Pillow's ({exc})") from None
        except (OSError, SyntaxError, ValueError, EOFError, Warning) as exc:
            if str(exc).startswith(str(path)):
                raise
            raise ValueError(f"{path}: the image file is damaged or truncated "
                             f"({type(exc).__name__}: {exc})") from None


_DECODE_LOCK = threading.Lock()
# Decoder messages about metadata, not pixels: passed on, not refused.
_BENIGN = re.compile(r"iCCP|sRGB|profile|Unknown field with tag|exif", re.IGNORECASE)


def _decode(path: Path, data: bytes) -> NDArray | None:
    """OpenCV's decoding, with the decoders' warnings (written to fd 2) turned into errors.

    libjpeg reports a damaged scan ("Corrupt JPEG data: ...") only as a
    warning on the process's standard error; the pixels it returns are not
    the file's.
    """
    # fd 2 is the process's: one redirection at a time, whatever the threads.
    with _DECODE_LOCK, tempfile.TemporaryFile() as sink:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            raw = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        sink.seek(0)
        said = sink.read().decode("utf-8", "replace").splitlines()
    harmful = [line.strip() for line in said if line.strip() and not _BENIGN.search(line)]
    benign = [line for line in said if line.strip() and _BENIGN.search(line)]
    if benign:
        sys.stderr.write("\n".join(benign) + "\n")
    if harmful:
        raise ValueError(f"{path}: the image file is damaged (the decoder warned: "
                         f"{'; '.join(harmful[:3])})")
    return raw


def read_image(path: str | Path) -> NDArray[np.float64]:
    """Read an image file as grey levels in ``[0, 1]``.

    Grey, RGB, RGBA, 8- and 16-bit files in any format OpenCV reads; see
    the module's limits. A photograph's EXIF orientation is applied: the
    pixels come upright, as a camera app shows them.

    Parameters
    ----------
    path : str or Path
        Image file.

    Returns
    -------
    ndarray, shape (H, W), float64

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file cannot be decoded as an image, is damaged or truncated,
        is over the pixel limit, or the image is empty.
    """
    # OpenCV decodes colour as BGR(A).
    return as_gray_float(_read_upright(Path(path)), name=str(path), channels="bgr")


def read_bgr8(path: str | Path) -> NDArray[np.uint8]:
    """Read an image file as 8-bit BGR colour, ``(H, W, 3)``, upright; checked and refused
    as :func:`read_image` (a grey file gives three equal channels)."""
    raw = _read_upright(Path(path))
    as_gray_float(raw, name=str(path), channels="bgr")   # its pixel type, size and values
    if raw.dtype == np.uint16:
        raw = (raw >> 8).astype(np.uint8)
    elif raw.dtype != np.uint8:
        raw = np.round(np.clip(raw.astype(np.float64), 0.0, 1.0) * 255).astype(np.uint8)
    if raw.ndim == 2 or raw.shape[2] == 1:
        return np.ascontiguousarray(np.repeat(raw.reshape(raw.shape[0], raw.shape[1], 1), 3,
                                              axis=2))
    return np.ascontiguousarray(raw[..., :3])


def _read_upright(path: Path) -> NDArray:
    """The file's decoded pixels as stored by OpenCV (BGR(A), any depth), turned upright."""
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    # No image within the pixel limit needs more than 8 bytes a pixel on disk.
    most = 8 * MAX_IMAGE_PIXELS + (1 << 20)
    size = path.stat().st_size
    if size > most:
        raise ValueError(f"{path}: the file is {size:,} bytes, more than an image within the "
                         f"pixel limit ({MAX_IMAGE_PIXELS:,}) can take")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    known, orientation = _check_file(path, data)
    raw = _decode(path, data) if data else None
    if raw is None and known is not None:
        raise ValueError(f"{path}: the image file is damaged or truncated (its {known} data "
                         "do not decode)")
    if raw is None:
        raise ValueError(f"{path}: cannot decode this file as an image (unreadable or not an image)")
    # The pixels as the photograph is seen (OpenCV's IMREAD_UNCHANGED keeps them as stored).
    return np.ascontiguousarray(_UPRIGHT[orientation](raw))


def read_mask(path: str | Path) -> NDArray[np.bool_]:
    """Read an object mask: any non-zero pixel belongs to the object."""
    gray = read_image(path)
    mask = gray > 0.5 * gray.max() if gray.max() > 0 else gray > 0
    if not mask.any():
        raise ValueError(f"{path}: the mask is empty (no pixel marks the object)")
    return mask


def load_image(image: str | Path | NDArray, *, name: str = "image", channels: str = "rgb"
               ) -> NDArray[np.float64]:
    """A grey float image from a path (:func:`read_image`) or an array (:func:`as_gray_float`).

    ``name`` labels an array in error messages; a path labels itself.
    ``channels`` is the colour order of an array (a file knows its own).
    """
    if isinstance(image, (str, Path)):
        return read_image(image)
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name}: expected an image file path or a numpy array, got "
                        f"{type(image).__name__}")
    return as_gray_float(image, name=name, channels=channels)
