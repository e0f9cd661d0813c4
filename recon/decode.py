"""Decode the De Bruijn fringe code along image rows.

Per row, fringes are the runs between deep minima of the value (brightness) profile (below
``BOUNDARY_DEPTH`` of the local maximum over one fringe width); each fringe's symbol is its
dominant colour after crosstalk correction, and its absolute index in the pattern follows from
the window-4 codes of the fringes around it (up to four windows vote). The result is a
per-pixel fringe index map (``-1`` where the code cannot be read: shadows, dark or ambiguous
fringes, row ends). The per-row loops are compiled (:func:`vbfe.recon.kernels.decode_rows`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vbfe.drivers.projector.pattern import (
    DEFAULT_FRINGES,
    N_SYMBOLS,
    SYMBOL_CHANNEL_BGR,
    WINDOW,
    fringe_symbols,
)
from vbfe.recon import kernels
from vbfe.recon.color import ColorModel
from vbfe.recon.debruijn import code_lookup

MIN_VOTES = 2  # windows that must agree on a fringe's index
BOUNDARY_DEPTH = 0.6  # a minimum is a fringe boundary if below this fraction of the local maximum
MIN_FRINGE_VALUE = 0.2  # mean corrected brightness below which a fringe is unreadable (shadow)
MIN_PURITY = 0.25  # (top - second) / top colour share for a readable symbol
MAX_PERIOD_PX = 64.0
PERIOD_ROWS = 16  # rows whose mean spectrum gives the fringe period


@dataclass(frozen=True)
class FringeCode:
    """Decoded code of one image: per-pixel fringe index and corrected colour (descriptor)."""

    index: np.ndarray  # int16 H×W, absolute fringe index in the pattern, -1 unreadable
    colour: np.ndarray  # float32 (H/row_step)×W×3, crosstalk-corrected projected colour (BGR)
    period_px: float  # fringe width along the rows
    row_step: int = 1  # colour row k: the middle row of image rows k·row_step … (k+1)·row_step-1


def fringe_period_px(image: np.ndarray) -> float:
    """Dominant fringe width (pixels) along the rows of an image, from the mean row spectrum
    weighted by √frequency (tempering the surface texture's low-frequency energy, so the
    fringes stand out even when ambient light leaves them little contrast)."""
    rows = image[:: max(1, image.shape[0] // PERIOD_ROWS)]
    if rows.ndim == 3:  # brightest channel (numpy's max over a last axis of 3 is 15x slower)
        rows = np.maximum(np.maximum(rows[..., 0], rows[..., 1]), rows[..., 2])
    rows = rows.astype(np.float32)
    rows -= rows.mean(axis=1, keepdims=True)
    spectrum = np.abs(np.fft.rfft(rows, axis=1)).mean(axis=0)
    spectrum *= np.sqrt(np.arange(len(spectrum)))
    width = image.shape[1]
    lowest = int(np.ceil(width / MAX_PERIOD_PX))
    peak = lowest + int(np.argmax(spectrum[lowest:]))
    return width / max(peak, 1)


class FringeDecoder:
    """Decodes fringe indices of rectified images for one pattern and colour model."""

    def __init__(
        self,
        color_model: ColorModel | None = None,
        n_fringes: int = DEFAULT_FRINGES,
        row_step: int = 5,
    ) -> None:
        """``row_step`` > 1 decodes the middle row of each block of ``row_step`` rows and copies
        its code to the block's other rows (fringes run nearly vertically, and a match is
        accepted within ±1 px of the code, so fringes tilted by less than about 1 px per
        ``row_step // 2`` rows lose nothing)."""
        self.color_model = color_model or ColorModel.identity()
        self.row_step = max(1, int(row_step))
        self.lookup = code_lookup(fringe_symbols(n_fringes), N_SYMBOLS, WINDOW)
        self._channel_symbol = np.empty(3, np.int8)
        self._channel_symbol[list(SYMBOL_CHANNEL_BGR)] = np.arange(3)

    def decoded_rows(self, image: np.ndarray) -> np.ndarray:
        """The rows of ``image`` that are decoded: the middle row of each block of ``row_step``
        rows (of a shorter last block, its middle row)."""
        height, step = image.shape[0], self.row_step
        if height % step == 0:
            return image[(step - 1) // 2 :: step]
        first = np.arange(0, height, step)
        return image[first + (np.minimum(step, height - first) - 1) // 2]

    def period_px(self, image: np.ndarray) -> float:
        """Fringe width of a (rectified) image, on the rows that are decoded."""
        return fringe_period_px(self.decoded_rows(image))

    def decode(self, image: np.ndarray, period_px: float | None = None) -> FringeCode:
        """Fringe index of every pixel of a (rectified) BGR image."""
        height = image.shape[0]
        period = period_px or self.period_px(image)
        image = self.decoded_rows(image)
        window = max(3, int(round(3.5 * period)))
        colour, value = self.color_model.fringe_colour(image, window)
        value = cv2.GaussianBlur(value, (5, 1), sigmaX=max(0.5, period / 8))
        index = np.empty((height, image.shape[1]), np.int16)
        kernels.decode_rows(
            value[..., None],
            colour,
            max(3, int(round(period)) | 1) // 2,
            self.lookup,
            self._channel_symbol,
            BOUNDARY_DEPTH,
            MIN_FRINGE_VALUE,
            MIN_PURITY,
            N_SYMBOLS,
            WINDOW,
            MIN_VOTES,
            self.row_step,
            index,
        )
        return FringeCode(index=index, colour=colour, period_px=period, row_step=self.row_step)
