"""The ``gist`` descriptor: Oliva & Torralba's GIST as computed by LabelMe's ``LMgist``.

Steps (LMgist defaults): grayscale; resize so the image covers 256 x 256 and crop the centre
(``imresizecrop``); rescale intensities to [0, 255]; ``prefilt`` (log(I + 1), 5 px symmetric pad,
whitening by subtracting a Gaussian low-pass with fc = 4, division by 0.2 + local std); 32 px
symmetric boundary extension; a bank of 4 scales x 8 orientations of Gabor transfer functions
applied in the Fourier domain; magnitude of the response, cropped back to 256 x 256 and averaged
on a 4 x 4 grid of 64 x 64 blocks.

Output order is LMgist's: index = (scale * 8 + orientation) * 16 + column * 4 + row, scale 0 the
finest, orientation j at angle pi j / 8, blocks in column-major (MATLAB) order.

OpenCV is imported where it is used: the command line builds its options from this module's
declarations without loading it.
"""
from __future__ import annotations

from collections.abc import Mapping
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import Descriptor, DescriptorSpec

IMAGE_SIZE = 256
SCALES = 4
ORIENTATIONS = 8
GRID = 4
LENGTH = SCALES * ORIENTATIONS * GRID * GRID
PREFILTER_FC = 4.0
PREFILTER_PAD = 5
BOUNDARY = 32
#: Grey levels of contrast (after the resize, of 255) at or below which a frame is constant: the
#: resize leaves a constant frame a few 1e-5 uneven, which stretched to 0..255 was noise.
FLAT = 1e-3
#: Gabor transfer values below this (of a peak of 1) are left out of the products: the
#: descriptors move by less than 1e-6 relative.
BAND_FLOOR = 1e-7
#: Smallest decode (w, h) that keeps the result: the resize target times this factor
#: (docs/descriptors.md, "Reduced decode").
DECODE_FACTOR = 1


def resize_crop(gray: NDArray[np.uint8], size: int = IMAGE_SIZE) -> NDArray[np.float32]:
    """LMgist's ``imresizecrop``: scale so both sides cover ``size``, then crop the centre.

    Area interpolation when shrinking (anti-aliased, like MATLAB's imresize), bilinear when
    enlarging.
    """
    import cv2

    h, w = gray.shape
    factor = max(size / h, size / w)
    new_w, new_h = max(round(w * factor), size), max(round(h * factor), size)
    method = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
    image = cv2.resize(gray.astype(np.float32), (new_w, new_h), interpolation=method)
    top, left = (new_h - size) // 2, (new_w - size) // 2
    return image[top : top + size, left : left + size]


def _centred_frequencies(rows: int, cols: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """fx, fy (cycles per image) on an FFT grid, as ``fftshift(meshgrid(-n/2:n/2-1))``."""
    fy, fx = np.meshgrid(
        np.fft.ifftshift(np.arange(-(rows // 2), rows - rows // 2)),
        np.fft.ifftshift(np.arange(-(cols // 2), cols - cols // 2)),
        indexing="ij",
    )
    return fx.astype(np.float64), fy.astype(np.float64)


@lru_cache(maxsize=4)
def gabor_bank(rows: int, cols: int) -> NDArray[np.float32]:
    """LMgist's ``createGabor`` transfer functions, (32, rows, cols), scale-major.

    Scale i (0 = finest), orientation j of 8: peak frequency 0.3 / 1.85^i cycles/pixel, radial
    parameter 0.35, angular parameter 16 * 8^2 / 32^2, angle pi j / 8;
    ``G = exp(-10 * 0.35 * (f / cols / f_peak - 1)^2 - 2 * a * pi * dtheta^2)``.
    """
    fx, fy = _centred_frequencies(rows, cols)
    radius = np.hypot(fx, fy)
    theta = np.arctan2(fy, fx)
    angular = 16.0 * ORIENTATIONS**2 / 32.0**2
    bank = np.empty((SCALES * ORIENTATIONS, rows, cols), dtype=np.float32)
    for scale in range(SCALES):
        peak = 0.3 / 1.85**scale
        radial = -10.0 * 0.35 * (radius / cols / peak - 1.0) ** 2
        for orientation in range(ORIENTATIONS):
            dtheta = theta + np.pi * orientation / ORIENTATIONS
            dtheta = dtheta + 2 * np.pi * (dtheta < -np.pi) - 2 * np.pi * (dtheta > np.pi)
            bank[scale * ORIENTATIONS + orientation] = np.exp(
                radial - 2.0 * angular * np.pi * dtheta**2
            )
    return _readonly(bank)


@lru_cache(maxsize=4)
def _prefilter_lowpass(n: int) -> NDArray[np.float32]:
    """``prefilt``'s Gaussian exp(-(fx^2 + fy^2) / s1^2) on an n x n grid (n even), laid out as
    OpenCV's packed spectrum of a real image (CCS): the filter is real and even, so every packed
    value, real or imaginary part, is multiplied by the gain at its frequency."""
    s1 = PREFILTER_FC / np.sqrt(np.log(2.0))
    fx, fy = _centred_frequencies(n, n)
    gain = np.exp(-(fx**2 + fy**2) / s1**2)
    half = n // 2
    packed = np.empty((n, n), dtype=np.float32)
    packed[:, 1 : n - 1] = np.repeat(gain[:, 1:half], 2, axis=1)  # (re, im) for fx = 1 .. n/2 - 1
    for column, kx in ((0, 0), (n - 1, half)):  # fx = 0 and n/2: the real spectrum's own CCS column
        packed[0, column] = gain[0, kx]
        packed[1 : n - 1, column] = np.repeat(gain[1:half, kx], 2)
        packed[n - 1, column] = gain[half, kx]
    return _readonly(packed)


@lru_cache(maxsize=4)
def _gabor_bands(rows: int, cols: int) -> tuple[tuple[int, int, NDArray[np.float32]], ...]:
    """Per filter of the bank, with rows reordered so that fy runs from -rows/2 up (a spectrum
    centred along y): the rows [start, stop) holding every value of at least BAND_FLOOR, and the
    filter there duplicated into two channels, to multiply OpenCV complex spectra. A filter is
    negligible elsewhere; its band is 5-100 % of the rows (half of all, on average)."""
    bands = []
    for transfer in np.fft.fftshift(gabor_bank(rows, cols), axes=1):
        kept = np.flatnonzero(transfer.max(axis=1) >= BAND_FLOOR)
        start, stop = int(kept[0]), int(kept[-1]) + 1
        bands.append((start, stop, _readonly(np.repeat(transfer[start:stop, :, None], 2, axis=2))))
    return tuple(bands)


def _readonly(array: NDArray) -> NDArray:
    array.setflags(write=False)
    return array


def _lowpass(image: NDArray[np.float32], lowpass: NDArray[np.float32]) -> NDArray[np.float32]:
    """Circular convolution with a real, even transfer function given in CCS layout
    (``real(ifft2(fft2(x) .* gf))``): OpenCV's real DFTs, 0.35 ms per filter on 266 x 266 against
    scipy.fft's 0.45-0.55."""
    import cv2

    spectrum = cv2.dft(image)
    return cv2.idft(cv2.multiply(spectrum, lowpass), flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)


def prefilter(image: NDArray[np.floating]) -> NDArray[np.float32]:
    """LMgist's ``prefilt``: log, whitening and local contrast normalisation (fc = 4).

    Single precision, as LMgist (which converts the image to ``single`` first). MATLAB's
    symmetric padding repeats the edge sample: OpenCV's ``BORDER_REFLECT``.
    """
    import cv2

    w = PREFILTER_PAD
    rows, cols = image.shape
    logged = np.log(image.astype(np.float32) + np.float32(1.0))
    padded = cv2.copyMakeBorder(logged, w, w, w, w, cv2.BORDER_REFLECT)
    n = max(padded.shape)
    n += n % 2
    padded = cv2.copyMakeBorder(padded, 0, n - padded.shape[0], 0, n - padded.shape[1], cv2.BORDER_REFLECT)
    lowpass = _prefilter_lowpass(n)
    whitened = padded - _lowpass(padded, lowpass)
    local_std = np.sqrt(np.abs(_lowpass(whitened * whitened, lowpass)))
    normalised = whitened / (np.float32(0.2) + local_std)
    return normalised[w : w + rows, w : w + cols]


def gist_of_prefiltered(image: NDArray[np.floating]) -> NDArray[np.float32]:
    """LMgist's ``gistGabor`` on a prefiltered image: 512 mean-pooled Gabor magnitudes.

    One filter at a time with OpenCV's complex DFT (a 320 x 320 spectrum and product stay in
    cache; docs/descriptors.md has the variants measured), into buffers reused across filters.
    The padded image is multiplied by (-1)^y, which centres its spectrum along y and only
    alternates the sign of each response's rows, not its magnitude: each filter's band is then
    one run of rows (`_gabor_bands`), and only the band is multiplied (the rows of the previous
    band outside it are zeroed). The forward DFT takes a complex image: from a real one,
    OpenCV's complex output costs 0.55 ms against 0.17. The inverse DFT is left unscaled and the
    pooled sums are divided by the number of samples instead.
    """
    import cv2

    b = BOUNDARY
    rows, cols = image.shape
    if rows % GRID or cols % GRID:
        raise ValueError(f"image sides must be multiples of {GRID}, got {image.shape}")
    padded = cv2.copyMakeBorder(image.astype(np.float32), b, b, b, b, cv2.BORDER_REFLECT)
    if padded.shape[0] % 2:
        raise ValueError(f"padded image rows must be even, got {padded.shape}")
    padded[1::2] *= np.float32(-1.0)
    spectrum = cv2.dft(cv2.merge([padded, np.zeros_like(padded)]), flags=cv2.DFT_COMPLEX_OUTPUT)
    product = np.zeros_like(spectrum)
    response = np.empty_like(spectrum)
    magnitude = np.empty((rows, cols), dtype=np.float32)
    bands = _gabor_bands(*padded.shape)
    pooled = np.empty((len(bands), GRID, GRID), dtype=np.float32)
    previous = (0, 0)
    for k, (start, stop, transfer) in enumerate(bands):
        product[previous[0] : start] = 0
        product[stop : previous[1]] = 0
        previous = (start, stop)
        cv2.multiply(spectrum[start:stop], transfer, dst=product[start:stop])
        cv2.idft(product, dst=response, flags=cv2.DFT_COMPLEX_OUTPUT)
        np.abs(response.view(np.complex64)[b : b + rows, b : b + cols, 0], out=magnitude)
        # downN: the sums over a GRID x GRID grid of blocks
        pooled[k] = magnitude.reshape(GRID, rows // GRID, cols).sum(axis=1).reshape(GRID, GRID, -1).sum(axis=2)
    pooled /= np.float32(padded.size * (rows // GRID) * (cols // GRID))
    # LMgist order: filter-major, blocks column-major (row index fastest).
    return pooled.transpose(0, 2, 1).reshape(-1)


def compute_gist(gray: NDArray[np.uint8]) -> NDArray[np.float32]:
    """The 512-value GIST descriptor of a grayscale image (float32, LMgist order)."""
    image = resize_crop(gray)
    image = image - image.min()
    top = image.max()
    if top > FLAT:  # a constant frame stays 0: the resize's rounding is no contrast to stretch
        image = image * np.float32(255.0 / top)
    else:
        image[...] = 0.0
    return gist_of_prefiltered(prefilter(image))


class Gist(Descriptor):
    """LabelMe's GIST compared by the squared Euclidean distance; no parameters."""

    name = "gist"
    metric = "sqeuclidean"
    version = 2  # 2: a constant frame's descriptor is 0 at any size (it was the resize's rounding, stretched)

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        side = IMAGE_SIZE * DECODE_FACTOR
        return cls._spec(params, dtype=np.dtype(np.float32), length=LENGTH, scale=1.0, min_size=(side, side),
                         natural_max=None)

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        return compute_gist(image)
