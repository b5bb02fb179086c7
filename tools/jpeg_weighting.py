"""Would a spot fit that models JPEG's quantisation place spots better? (issue 15, measured)

JPEG stores each 8 × 8 block's DCT coefficients rounded to steps that grow with frequency (quality
50: 10-16 at the lowest, up to 121 at the highest). The difference of a laser-on and a laser-off
frame therefore carries an error of about step²/6 per coefficient, far from the white noise a
pixel-by-pixel fit assumes. A fit weighted by it in the DCT domain (generalised least squares, each
coefficient by 1 / (step²/6 + 2 × read²)) is what "a localiser that models JPEG's quantisation"
would do first. This measures it against the same Gaussian fitted pixel by pixel, on grey frames
that OpenCV's libjpeg compresses (a flat wall with texture, the spot at a random sub-pixel place),
and against the pixel fit on the same frames uncompressed (what JPEG took away).

    .venv/bin/python tools/jpeg_weighting.py                 # the table, 300 spots a row
    .venv/bin/python tools/jpeg_weighting.py --spots 100 --seed 3

It asserts nothing: it prints each row's median and 90th-percentile position error (px), and how
many fits failed (off by over 4 px).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import cv2
import numpy as np

# The baseline luminance table of the JPEG standard (Annex K), scaled for a quality as libjpeg does.
LUMA_TABLE = np.array([
    16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
    14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
    49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99], float).reshape(8, 8)
SIZE = 48  # frame (px); the spot lies in the 2 × 2 blocks at 16-32, whose window is fitted
WINDOW = slice(16, 32)
READ_DN = 2.0  # sensor noise per frame (DN)
FAILED_PX = 4.0
# The orthonormal DCT-II matrix of 8 samples: a block's coefficients are D @ block @ D.T.
DCT8 = np.array([[np.sqrt((1 if k == 0 else 2) / 8) * np.cos((2 * n + 1) * k * np.pi / 16) for n in range(8)]
                 for k in range(8)])


def quant_table(quality: int) -> np.ndarray:
    scale = 5000 / quality if quality < 50 else 200 - 2 * quality
    return np.clip(np.floor((LUMA_TABLE * scale + 50) / 100), 1, 255)


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    pixels = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE).astype(float)


def block_dct(window: np.ndarray) -> np.ndarray:
    rows, cols = window.shape[0] // 8, window.shape[1] // 8
    return DCT8 @ window.reshape(rows, 8, cols, 8).transpose(0, 2, 1, 3) @ DCT8.T


GRID = np.mgrid[WINDOW, WINDOW].astype(float)  # (v, u) of the window's pixels


def spot_model(p: np.ndarray) -> np.ndarray:
    u, v, peak, width, level = p
    return peak * np.exp(-((GRID[1] - u) ** 2 + (GRID[0] - v) ** 2) / (2 * width * width)) + level


def gauss_newton(residual: Callable[[np.ndarray], np.ndarray], p0: np.ndarray) -> np.ndarray:
    p = p0.astype(float)
    for _ in range(30):
        r = residual(p)
        jac = np.empty((r.size, p.size))
        for i in range(p.size):
            dp = np.zeros(p.size)
            dp[i] = 1e-4 * max(1.0, abs(p[i]))
            jac[:, i] = (residual(p + dp) - r) / dp[i]
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        p += step
        p[3] = max(p[3], 0.3)
        if np.abs(step[:2]).max() < 1e-5:
            break
    return p


def fit_pixels(window: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """The Gaussian fitted pixel by pixel (white noise)."""
    return gauss_newton(lambda p: (window - spot_model(p)).ravel(), p0)


def fit_dct(window: np.ndarray, weights: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """The Gaussian fitted to the window's block DCT, each coefficient weighed by `weights`."""
    return gauss_newton(lambda p: (block_dct(window - spot_model(p)) * weights).ravel(), p0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spots", type=int, default=300, help="spots per row")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"{'quality':>7s} {'peak DN':>7s} {'width px':>8s}   {'uncompressed':>14s} {'JPEG, pixels':>14s} "
          f"{'JPEG, DCT-weighted':>19s}   (median / 90 % error, px; failed)")
    for quality, peak, width in ((50, 15, 1.2), (50, 40, 1.2), (70, 15, 1.2), (70, 40, 1.5), (90, 15, 1.2),
                                 (50, 10, 2.0)):
        rng = np.random.default_rng(args.seed)
        weights = 1.0 / np.sqrt(quant_table(quality) ** 2 / 6 + 2 * READ_DN**2)
        errors: dict[str, list[float]] = {"raw": [], "pixels": [], "dct": []}
        yy, xx = np.mgrid[0:SIZE, 0:SIZE].astype(float)
        for _ in range(args.spots):
            room = 90 + 25 * cv2.GaussianBlur(rng.standard_normal((SIZE, SIZE)), (0, 0), 2.0)
            u, v = 20 + 8 * rng.random(), 20 + 8 * rng.random()
            spot = peak * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * width * width))
            off_raw = room + READ_DN * rng.standard_normal((SIZE, SIZE))
            on_raw = room + spot + READ_DN * rng.standard_normal((SIZE, SIZE))
            raw = (on_raw - off_raw)[WINDOW, WINDOW]
            comp = (jpeg(on_raw, quality) - jpeg(off_raw, quality))[WINDOW, WINDOW]
            p0 = np.array([round(u), round(v), max(float(comp[round(v) - 16, round(u) - 16]), 1.0), 1.5, 0.0])
            fits = {"raw": fit_pixels(raw, p0), "pixels": fit_pixels(comp, p0), "dct": fit_dct(comp, weights, p0)}
            for name, p in fits.items():
                errors[name].append(float(np.hypot(p[0] - u, p[1] - v)))
        cells = []
        for name in ("raw", "pixels", "dct"):
            e = np.array(errors[name])
            good = e[e <= FAILED_PX]
            cells.append(f"{np.median(good):.3f} / {np.percentile(good, 90):.3f}; {np.sum(e > FAILED_PX):2d}")
        print(f"{quality:7d} {peak:7.0f} {width:8.1f}   {cells[0]:>14s} {cells[1]:>14s} {cells[2]:>19s}")


if __name__ == "__main__":
    main()
