"""A frame-ID patch stamped into projected patterns so captured images can be matched to them.

The patch is one row of square cells in the top-left corner: a white and a black reference cell,
``n_bits`` data cells (most significant first, white = 1) and an even-parity cell. The
references make decoding independent of projector brightness and camera exposure.
"""

from __future__ import annotations

import numpy as np

N_BITS = 16


def _cells(frame_id: int, n_bits: int) -> list[int]:
    bits = [(frame_id >> (n_bits - 1 - i)) & 1 for i in range(n_bits)]
    return [1, 0, *bits, sum(bits) % 2]


def patch_size(cell_px: int = 8, n_bits: int = N_BITS) -> tuple[int, int]:
    """Width and height in pixels of the stamped patch."""
    return (n_bits + 3) * cell_px, cell_px


def stamp_frame_id(
    image: np.ndarray, frame_id: int, cell_px: int = 8, n_bits: int = N_BITS
) -> np.ndarray:
    """A copy of ``image`` (H×W×3 or H×W) with ``frame_id mod 2**n_bits`` stamped top-left."""
    width, height = patch_size(cell_px, n_bits)
    if image.shape[0] < height or image.shape[1] < width:
        raise ValueError(
            f"image {image.shape[1]}x{image.shape[0]} is smaller than the "
            f"{width}x{height} frame-ID patch"
        )
    out = image.copy()
    cells = np.repeat(np.array(_cells(frame_id % (1 << n_bits), n_bits), np.uint8) * 255, cell_px)
    out[:height, :width] = cells[None, :, None] if out.ndim == 3 else cells[None, :]
    return out


def decode_frame_id(image_region: np.ndarray, n_bits: int = N_BITS) -> int | None:
    """The frame ID in a region that holds exactly the patch (any scale, BGR or grey).

    Returns ``None`` when the reference cells show no contrast or the parity check fails.
    """
    grey = image_region.astype(np.float64)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    n_cells = n_bits + 3
    edges = np.linspace(0, grey.shape[1], n_cells + 1)
    h = grey.shape[0]
    values = []
    for left, right in zip(edges[:-1], edges[1:], strict=False):
        margin = (right - left) / 4  # sample the cell's centre, away from blurred edges
        rows = slice(h // 4, h - h // 4 or h)
        values.append(grey[rows, int(left + margin) : int(np.ceil(right - margin))].mean())
    white, black = values[0], values[1]
    if white - black < 16:
        return None
    bits = [int(v > (white + black) / 2) for v in values[2:]]
    if sum(bits[:-1]) % 2 != bits[-1]:
        return None
    return int("".join(map(str, bits[:-1])), 2)
