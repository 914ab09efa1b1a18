"""Reading images into the one form every later stage expects."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray


def as_gray_float(image: NDArray, *, name: str = "image") -> NDArray[np.float64]:
    """Convert an image array to grey levels in ``[0, 1]``.

    Accepts grey ``(H, W)``, RGB ``(H, W, 3)`` and RGBA ``(H, W, 4)`` arrays of
    ``uint8``, ``uint16`` or float type (floats are taken to be in ``[0, 1]``).
    Colour channels are taken in RGB order; the alpha channel is ignored.

    Parameters
    ----------
    image : ndarray
        The image.
    name : str, optional
        How to name the image in error messages (a file name, an argument).

    Returns
    -------
    ndarray, shape (H, W), float64

    Raises
    ------
    TypeError
        If ``image`` is not an array of a supported type.
    ValueError
        If it is empty, of an unsupported shape, or holds NaN or infinity.
    """
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
    if rgb.dtype == np.uint8:
        scaled = rgb.astype(np.float64) / 255.0
    elif rgb.dtype == np.uint16:
        scaled = rgb.astype(np.float64) / 65535.0
    elif rgb.dtype == np.bool_:
        scaled = rgb.astype(np.float64)
    elif np.issubdtype(rgb.dtype, np.floating):
        scaled = rgb.astype(np.float64)
        if not np.all(np.isfinite(scaled)):
            raise ValueError(f"{name}: the image holds NaN or infinite values")
    else:
        raise TypeError(f"{name}: unsupported pixel type {rgb.dtype}; use uint8, uint16 or float")
    if scaled.ndim == 3:
        scaled = scaled @ np.array([0.299, 0.587, 0.114])
    return np.ascontiguousarray(scaled)


def read_image(path: str | Path) -> NDArray[np.float64]:
    """Read an image file as grey levels in ``[0, 1]``.

    Grey, RGB, RGBA, 8- and 16-bit files in any format OpenCV reads.

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
        If the file cannot be decoded as an image or the image is empty.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ValueError(f"{path}: cannot decode this file as an image (unreadable or not an image)")
    if raw.ndim == 3 and raw.shape[2] >= 3:
        # OpenCV decodes colour as BGR(A).
        raw = np.concatenate([raw[..., 2::-1], raw[..., 3:]], axis=2)
    return as_gray_float(raw, name=str(path))


def read_mask(path: str | Path) -> NDArray[np.bool_]:
    """Read an object mask: any non-zero pixel belongs to the object."""
    gray = read_image(path)
    mask = gray > 0.5 * gray.max() if gray.max() > 0 else gray > 0
    if not mask.any():
        raise ValueError(f"{path}: the mask is empty (no pixel marks the object)")
    return mask


def load_image(image: str | Path | NDArray, *, name: str = "image") -> NDArray[np.float64]:
    """A grey float image from a path (:func:`read_image`) or an array (:func:`as_gray_float`).

    ``name`` labels an array in error messages; a path labels itself.
    """
    if isinstance(image, (str, Path)):
        return read_image(image)
    return as_gray_float(image, name=name)
