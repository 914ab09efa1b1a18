"""LINE-2D timing for benchmarks/speed.py, run in a virtual environment with opencv-contrib.

opencv-contrib replaces the project's OpenCV, so this file imports only cv2
and numpy. It reads a JSON job (training images with boxes, test images,
scales), builds one ``cv2.linemod`` LINE detector with a template per
training image and scale (the box as the mask), matches every test image
once to compile nothing, then times each match, and prints a JSON line.
"""

from __future__ import annotations

import json
import sys
import time

import cv2
import numpy as np


def _template(image, box, scale):
    """The box and a margin, scaled, padded to a multiple of 16 pixels (linemod's pyramid)."""
    x, y, w, h = (int(round(b)) for b in box)
    m = 8
    x0, y0 = max(x - m, 0), max(y - m, 0)
    crop = image[y0:min(y + h + m, image.shape[0]), x0:min(x + w + m, image.shape[1])]
    crop = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    ph, pw = -crop.shape[0] % 16, -crop.shape[1] % 16
    crop = cv2.copyMakeBorder(crop, 0, ph, 0, pw, cv2.BORDER_REPLICATE)
    mask = np.zeros(crop.shape[:2], dtype=np.uint8)
    mask[int((y - y0) * scale):int((y - y0 + h) * scale),
         int((x - x0) * scale):int((x - x0 + w) * scale)] = 255
    return np.ascontiguousarray(crop), mask


def main() -> int:
    job = json.loads(open(sys.argv[1]).read())
    cv2.setNumThreads(1)
    detector = cv2.linemod.getDefaultLINE()
    added = 0
    start = time.perf_counter()
    for path, box in zip(job["train"], job["boxes"], strict=True):
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        for scale in job["scales"]:
            template, mask = _template(image, box, scale)
            template_id, _ = detector.addTemplate([template], "object", mask)
            added += int(template_id >= 0)
    build = time.perf_counter() - start
    # linemod needs a height that is a multiple of 80 (T = 5 and 8 on two levels) and a
    # width that is a multiple of 160 as well (opencv issue 29559: its SSE stores crash
    # otherwise); the frames are padded to that, which LINE-2D pays for.
    tests = [cv2.imread(p, cv2.IMREAD_COLOR) for p in job["test"]]
    tests = [cv2.copyMakeBorder(t, 0, -t.shape[0] % 80, 0, -t.shape[1] % 160,
                                cv2.BORDER_REPLICATE) for t in tests]
    detector.match([tests[0]], job["threshold"])
    seconds = []
    for image in tests:
        t0 = time.perf_counter()
        detector.match([image], job["threshold"])
        seconds.append(time.perf_counter() - t0)
    print(json.dumps({"templates": added, "build_seconds": build, "seconds": seconds,
                      "opencv": cv2.__version__}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
