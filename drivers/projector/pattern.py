"""The one-shot projector pattern: De Bruijn-coded hue, full saturation, cosine value per fringe.

The low module every package may import: the projector shows it (``acquire``, the simulated
bench) and the reconstruction decodes it (``recon``).

Fringes are vertical (the code varies along x, the stereo epipolar direction). Fringe ``k`` has
the hue of symbol ``s[k]`` of the De Bruijn sequence B(3, 4) (0 = red, 1 = green, 2 = blue), and
``V = 0.5 + 0.5 cos(2π (x - centre_k) / width_k)`` so fringe centres are bright and the
boundaries between fringes dark.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vbfe.common.errors import DeviceError

N_SYMBOLS = 3  # red, green, blue
WINDOW = 4  # De Bruijn window length: B(3, 4) has 81 symbols
DEFAULT_FRINGES = 64
PATTERN_NAME = "debruijn-hsv"  # how projector events and sessions name make_pattern's image
SYMBOL_CHANNEL_BGR = (2, 1, 0)  # symbol -> BGR channel index (red, green, blue)


def de_bruijn(n_symbols: int = 3, order: int = 4) -> np.ndarray:
    """The lexicographically least De Bruijn sequence B(n, m) (length n**m), as int8 symbols.

    Built with the Fredricksen–Kessler–Maiorana algorithm (concatenated Lyndon words).
    """
    a = [0] * (n_symbols * order)
    out: list[int] = []

    def db(t: int, p: int) -> None:
        if t > order:
            if order % p == 0:
                out.extend(a[1 : p + 1])
            return
        a[t] = a[t - p]
        db(t + 1, p)
        for j in range(a[t - p] + 1, n_symbols):
            a[t] = j
            db(t + 1, t)

    db(1, 1)
    return np.asarray(out, dtype=np.int8)


def fringe_symbols(n_fringes: int = DEFAULT_FRINGES) -> np.ndarray:
    """Colour symbol of each fringe: the first ``n_fringes`` symbols of B(3, 4)."""
    sequence = de_bruijn(N_SYMBOLS, WINDOW)
    if not WINDOW <= n_fringes <= len(sequence):
        raise DeviceError(f"n_fringes must be in [{WINDOW}, {len(sequence)}], got {n_fringes}")
    return sequence[:n_fringes]


def fringe_coordinates(
    width: int, n_fringes: int = DEFAULT_FRINGES
) -> tuple[np.ndarray, np.ndarray]:
    """For each projector column: fringe index (int) and phase within the fringe in [0, 1)."""
    position = (np.arange(width) + 0.5) * n_fringes / width
    index = np.minimum(np.floor(position).astype(np.int32), n_fringes - 1)
    return index, position - index


def make_pattern(width: int, height: int, n_fringes: int = DEFAULT_FRINGES) -> np.ndarray:
    """The pattern as a BGR ``uint8`` image of ``height × width`` (projector resolution)."""
    if width < 2 * n_fringes or height < 1:
        raise DeviceError(
            f"pattern of {width}x{height} px is too small for {n_fringes} fringes "
            f"(need at least 2 px per fringe)"
        )
    symbols = fringe_symbols(n_fringes)
    index, phase = fringe_coordinates(width, n_fringes)
    value = 0.5 - 0.5 * np.cos(2 * np.pi * phase)  # 1 at the fringe centre (phase 0.5), 0 at edges
    hsv = np.empty((1, width, 3), dtype=np.float32)
    hsv[0, :, 0] = symbols[index] * 120.0  # OpenCV float HSV: hue in degrees
    hsv[0, :, 1] = 1.0
    hsv[0, :, 2] = value
    row = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    row = np.clip(np.rint(row * 255.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(np.broadcast_to(row, (height, width, 3)))


def save_pattern(
    path: str | Path, width: int, height: int, n_fringes: int = DEFAULT_FRINGES
) -> Path:
    """Write the pattern as a PNG for a projector of ``width × height`` pixels."""
    path = Path(path)
    if not cv2.imwrite(str(path), make_pattern(width, height, n_fringes)):
        raise DeviceError(
            f"could not write pattern image {path}; check the folder exists and the "
            f"name ends in .png"
        )
    return path
