import cv2
import numpy as np
import pytest

from posevote.data import as_gray_float, read_bgr8, read_image, read_mask


def test_accepts_grey_rgb_rgba_16bit(tmp_path):
    grey = (np.arange(64, dtype=np.uint8).reshape(8, 8) * 4)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    cv2.imwrite(str(tmp_path / "c.png"), np.dstack([grey] * 3))
    cv2.imwrite(str(tmp_path / "a.png"), np.dstack([grey] * 3 + [np.full_like(grey, 255)]))
    cv2.imwrite(str(tmp_path / "w.png"), grey.astype(np.uint16) * 257)
    ref = read_image(tmp_path / "g.png")
    assert ref.shape == (8, 8) and ref.dtype == np.float64
    for name in ("c.png", "a.png", "w.png"):
        assert np.allclose(read_image(tmp_path / name), ref, atol=1 / 255)


def test_colour_files_read_as_8_bit_bgr(tmp_path):
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 0], bgr[..., 2] = 200, 40
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    cv2.imwrite(str(tmp_path / "w.png"), bgr.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "g.png"), bgr[..., 0])
    assert np.array_equal(read_bgr8(tmp_path / "c.png"), bgr)
    assert np.array_equal(read_bgr8(tmp_path / "w.png"), bgr)
    grey = read_bgr8(tmp_path / "g.png")
    assert grey.shape == (4, 6, 3) and np.all(grey == 200)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="bad.png"):
        read_bgr8(tmp_path / "bad.png")


def test_colour_order_is_rgb():
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 255
    assert as_gray_float(red)[0, 0] == pytest.approx(0.299)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="image file not found"):
        read_image(tmp_path / "nope.png")


def test_unreadable_file(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image at all")
    with pytest.raises(ValueError, match="bad.png: cannot decode"):
        read_image(bad)


def test_empty_and_nan_arrays():
    with pytest.raises(ValueError, match="empty"):
        as_gray_float(np.zeros((0, 5)), name="img")
    with pytest.raises(ValueError, match="NaN"):
        as_gray_float(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="grey"):
        as_gray_float(np.zeros((3, 3, 2)))
    with pytest.raises(TypeError, match="numpy array"):
        as_gray_float([[0.0]])
    with pytest.raises(TypeError, match="pixel type"):
        as_gray_float(np.zeros((3, 3), dtype=np.int32))


def test_read_mask(tmp_path):
    m = np.zeros((6, 6), np.uint8)
    m[2:4, 2:5] = 255
    cv2.imwrite(str(tmp_path / "m.png"), m)
    assert read_mask(tmp_path / "m.png").sum() == 6
    cv2.imwrite(str(tmp_path / "e.png"), np.zeros((6, 6), np.uint8))
    with pytest.raises(ValueError, match="mask is empty"):
        read_mask(tmp_path / "e.png")


def test_load_image_takes_a_path_or_an_array(tmp_path):
    import cv2

    from posevote.data.images import load_image

    grey = np.zeros((6, 8), np.uint8)
    grey[2, 3] = 255
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    np.testing.assert_allclose(load_image(tmp_path / "g.png"), load_image(grey))
    with pytest.raises(ValueError, match="frame"):
        load_image(np.zeros((2, 2, 7)), name="frame")


@pytest.mark.parametrize("orientation", range(1, 9))
def test_a_photographs_exif_orientation_is_applied(tmp_path, orientation):
    from PIL import Image, ImageOps

    pixels = (np.random.default_rng(0).random((40, 60)) * 255).astype(np.uint8)
    im = Image.fromarray(pixels)
    exif = im.getexif()
    exif[0x0112] = orientation
    path = tmp_path / "photo.jpg"
    im.save(path, exif=exif, quality=95)
    with Image.open(path) as shown:
        upright = np.asarray(ImageOps.exif_transpose(shown).convert("L"), dtype=np.float64)
    got = read_image(path)
    assert got.shape == ((40, 60) if orientation < 5 else (60, 40))
    np.testing.assert_allclose(got, upright / 255.0, atol=1e-12)
