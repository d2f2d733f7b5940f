"""The three whole-image descriptors and the registry (wiloc/descriptors)."""
from __future__ import annotations

import multiprocessing
from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc.descriptors import (
                               DESCRIPTOR_NAMES,
                               METRICS,
                               brisk_gist,
                               get_descriptor,
                               gist,
                               registry,
                               sad,
                               )
from wiloc.errors import ParameterError
from wiloc.sources.frames import read_gray


def _textured(h: int, w: int, seed: int = 0, sigma: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (h, w), dtype=np.uint8)
    return cv2.GaussianBlur(noise, (0, 0), sigma)


# ----------------------------------------------------------------------------- registry

@pytest.mark.parametrize("name", DESCRIPTOR_NAMES)
def test_spec_compute_gives_length_and_dtype(name: str) -> None:
    spec = get_descriptor(name)
    out = spec.compute(_textured(120, 200))
    assert out.shape == (spec.length,) and out.dtype == spec.dtype
    assert spec.metric in ("l1", "sqeuclidean", "hamming")
    assert spec.min_size is not None and spec.scale > 0


def test_unknown_names_and_params_list_the_choices() -> None:
    with pytest.raises(ValueError, match="sad, gist, brisk-gist"):
        get_descriptor("surf")
    with pytest.raises(ParameterError, match=r"size: not a parameter of descriptor 'sad' \(valid: crop, patch, storage\)"):
        get_descriptor("sad", size=3)
    with pytest.raises(ParameterError, match="crop: must be one of none, top-half, got 'bottom'"):
        get_descriptor("sad", crop="bottom")
    with pytest.raises(ParameterError, match=r"patch: must divide .* \(one of 2, 3, 4, 6, 8, 12, 24\)"):
        get_descriptor("sad", patch=5)
    with pytest.raises(ParameterError, match=r"keypoint_size: must lie in \[4, 96\]"):
        get_descriptor("brisk-gist", keypoint_size=2)
    with pytest.raises(ValueError, match="uint8"):
        get_descriptor("external", metric="hamming", length=8, dtype="float32")


def test_params_are_complete_so_cache_keys_agree() -> None:
    assert get_descriptor("sad").key == get_descriptor("sad", crop="none", patch=8).key
    assert get_descriptor("sad").key != get_descriptor("sad", crop="top-half").key


def _compute_in_worker(spec_and_image: tuple) -> np.ndarray:
    spec, image = spec_and_image
    return spec.compute(image)


def test_specs_compute_in_a_worker_process() -> None:
    image = _textured(60, 80)
    specs = [get_descriptor(name) for name in DESCRIPTOR_NAMES]
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        remote = pool.map(_compute_in_worker, [(s, image) for s in specs])
    for spec, out in zip(specs, remote):
        assert np.array_equal(out, spec.compute(image))


# ----------------------------------------------------------------------------- sad

def test_sad_blocks_are_zero_mean_unit_std_or_zero() -> None:
    image = _textured(240, 320, sigma=6)
    image[:120, :160] = 77  # constant area: its blocks must normalise to exactly 0
    z = sad.sad_z(image).astype(np.float64)
    blocks = z.reshape(3, 8, 6, 8).transpose(0, 2, 1, 3).reshape(18, 64)
    flat = np.all(blocks == 0, axis=1)
    assert flat.sum() >= 3  # the 1 x 3 blocks wholly inside the constant area (12 x 24 px)
    assert np.allclose(blocks[~flat].mean(axis=1), 0, atol=1e-5)
    assert np.allclose(blocks[~flat].std(axis=1), 1, atol=1e-5)


def test_sad_quantisation_round_trip() -> None:
    z = np.linspace(-6, 6, 1152, dtype=np.float32).reshape(24, 48)
    back = sad.dequantise(sad.quantise(z, "uint8"), "uint8").reshape(24, 48)
    inside = np.abs(z) <= 3.95
    assert np.abs(back - z)[inside].max() <= 0.5 / 32 + 1e-6
    assert back.min() >= -4.0 and back.max() <= 127 / 32  # clipped to 0..255
    coarse = sad.dequantise(sad.quantise(z, "seqslam"), "seqslam").reshape(24, 48)
    assert np.abs(coarse - z).max() <= 0.5 + 1e-6
    assert np.array_equal(sad.dequantise(sad.quantise(z, "float32"), "float32").reshape(24, 48), z)


@pytest.mark.parametrize("storage", sad.STORAGES)
def test_sad_scale_gives_mean_absolute_z_difference(storage: str) -> None:
    a, b = _textured(96, 128, 1), _textured(96, 128, 2)
    za, zb = sad.sad_z(a), sad.sad_z(b)
    qa, qb = (sad.compute_sad(x, storage=storage).astype(np.float64) for x in (a, b))
    d = np.abs(qa - qb).sum() * sad.scale(storage)
    step = {"uint8": 1 / 32, "float32": 1e-6, "seqslam": 1.0}[storage]
    assert abs(d - np.abs(za - zb).mean()) <= step
    # Natural maximum: a thumbnail against its negative is as different as blocks can be.
    qn = sad.quantise(-za, storage).astype(np.float64)
    assert np.abs(qa - qn).sum() * sad.scale(storage) <= sad.natural_max(storage)


def test_sad_top_half_ignores_the_bottom() -> None:
    a = _textured(100, 200)
    b = a.copy()
    b[50:] = 255 - b[50:]
    assert np.array_equal(sad.compute_sad(a, crop="top-half"), sad.compute_sad(b, crop="top-half"))
    assert not np.array_equal(sad.compute_sad(a), sad.compute_sad(b))


# ----------------------------------------------------------------------------- gist

def _lmgist_reference(img: np.ndarray) -> np.ndarray:
    """A literal float64 transcription of LMgist (prefilt, createGabor, gistGabor, downN)."""
    # prefilt(img, 4)
    w, fc = 5, 4.0
    s1 = fc / np.sqrt(np.log(2))
    x = np.pad(np.log(img + 1.0), w, mode="symmetric")
    sn, sm = x.shape
    n = max(sn, sm)
    n += n % 2
    x = np.pad(x, ((0, n - sn), (0, n - sm)), mode="symmetric")
    fx, fy = np.meshgrid(np.arange(-n / 2, n / 2), np.arange(-n / 2, n / 2))
    gf = np.fft.fftshift(np.exp(-(fx**2 + fy**2) / s1**2))
    out = x - np.real(np.fft.ifft2(np.fft.fft2(x) * gf))
    localstd = np.sqrt(np.abs(np.fft.ifft2(np.fft.fft2(out**2) * gf)))
    out = (out / (0.2 + localstd))[w : sn - w, w : sm - w]
    # createGabor([8 8 8 8], 256 + 64)
    be, size = 32, 256 + 64
    fx, fy = np.meshgrid(np.arange(-size / 2, size / 2), np.arange(-size / 2, size / 2))
    fr = np.fft.fftshift(np.sqrt(fx**2 + fy**2))
    t = np.fft.fftshift(np.angle(fx + 1j * fy))
    filters = []
    for i in range(1, 5):
        for j in range(1, 9):
            a, f0, b, ang = 0.35, 0.3 / 1.85 ** (i - 1), 16 * 8**2 / 32**2, np.pi / 8 * (j - 1)
            tr = t + ang
            tr = tr + 2 * np.pi * (tr < -np.pi) - 2 * np.pi * (tr > np.pi)
            filters.append(np.exp(-10 * a * (fr / size / f0 - 1) ** 2 - 2 * b * np.pi * tr**2))
    # gistGabor with downN(., 4), MATLAB column-major reshape of each 4 x 4 block grid
    spec = np.fft.fft2(np.pad(out, be, mode="symmetric"))
    g = []
    for G in filters:
        ig = np.abs(np.fft.ifft2(spec * G))[be : size - be, be : size - be]
        edges = np.fix(np.linspace(0, 256, 5)).astype(int)
        v = np.array([[ig[edges[r] : edges[r + 1], edges[c] : edges[c + 1]].mean()
                       for c in range(4)] for r in range(4)])
        g.extend(v.flatten(order="F"))
    return np.array(g)


def _gist_input(gray: np.ndarray) -> np.ndarray:
    image = gist.resize_crop(gray).astype(np.float64)
    image -= image.min()
    return 255 * image / image.max()


def test_gist_matches_lmgist_transcription() -> None:
    gray = _textured(300, 420, seed=5, sigma=3)
    ours = gist.compute_gist(gray)
    ref = _lmgist_reference(_gist_input(gray))
    assert ours.shape == (512,) and ours.dtype == np.float32
    assert np.abs(ours - ref).max() <= 1e-4 * ref.max()


@pytest.mark.realdata
def test_gist_matches_lmgist_transcription_on_a_real_frame(data_root: Path) -> None:
    gray = read_gray(data_root / "gardens-point-walking" / "day_left" / "Image050.jpg")
    ref = _lmgist_reference(_gist_input(gray))
    assert np.abs(gist.compute_gist(gray) - ref).max() <= 1e-4 * ref.max()


def _grating(frequency: float, angle: float, size: int = 256) -> np.ndarray:
    """A sinusoid whose spatial frequency vector is frequency * (cos angle, -sin angle)."""
    y, x = np.mgrid[:size, :size].astype(np.float64)
    phase = 2 * np.pi * frequency * (np.cos(angle) * x - np.sin(angle) * y)
    return np.rint(128 + 100 * np.cos(phase)).astype(np.uint8)


@pytest.mark.parametrize(
    ("scale", "orientation"), [(0, 0), (1, 2), (1, 5), (2, 4), (3, 6), (2, 1), (0, 7), (3, 3)]
)
def test_gist_grating_excites_its_scale_and_orientation(scale: int, orientation: int) -> None:
    image = _grating(0.3 / 1.85**scale, np.pi * orientation / 8)
    energy = gist.compute_gist(image).reshape(4, 8, 16).mean(axis=2)
    assert np.unravel_index(np.argmax(energy), energy.shape) == (scale, orientation)


def test_gist_blocks_are_mean_pooled_in_column_major_order() -> None:
    image = np.full((256, 256), 128, np.uint8)
    image[:64, 128:192] = _textured(64, 64, sigma=1.0)  # block row 0, column 2 only
    g = gist.compute_gist(image).reshape(32, 4, 4)  # (filter, column, row)
    per_block = g.sum(axis=0)
    assert np.unravel_index(np.argmax(per_block), per_block.shape) == (2, 0)
    # Mean pooling: the textured block's value is the mean of the full-resolution magnitude.
    ref = _lmgist_reference(_gist_input(image)).reshape(32, 4, 4)
    assert np.allclose(g, ref, rtol=0, atol=1e-4 * ref.max())


@pytest.mark.parametrize("shape", [(50, 80), (540, 960)])
@pytest.mark.parametrize("value", [0, 128, 200, 255])
def test_gist_constant_image_is_zero(shape: tuple[int, int], value: int) -> None:
    """The resize's float rounding leaves a constant frame (a lens cap, a saturated sky) a few
    1e-5 of a grey level uneven; stretched to 0..255, that noise was a descriptor far from every
    frame, other blank ones too (squared differences up to 5.2 among constant frames of 0, 64, 128,
    192 and 255 grey levels at 540 x 960)."""
    assert not np.any(gist.compute_gist(np.full(shape, value, np.uint8)))


# ----------------------------------------------------------------------------- brisk-gist

def test_brisk_gist_synthetic_gives_25_tiles_in_row_major_order() -> None:
    image = _textured(240, 240, seed=3, sigma=1.5)
    out = brisk_gist.compute_brisk_gist(image)
    assert out.shape == (1600,) and out.dtype == np.uint8
    tiles = out.reshape(25, 64)
    assert np.all(tiles.any(axis=1))
    changed = image.copy()
    changed[-40:, -40:] = 255 - changed[-40:, -40:]  # bottom-right corner only
    after = brisk_gist.compute_brisk_gist(changed).reshape(25, 64)
    assert np.array_equal(after[0], tiles[0]) and not np.array_equal(after[24], tiles[24])


@pytest.mark.parametrize("keypoint_size", [8.0, 24.0, 48.0, 96.0])
def test_brisk_gist_keeps_every_tile_for_any_keypoint_size(keypoint_size: float) -> None:
    out = brisk_gist.compute_brisk_gist(_textured(100, 300), keypoint_size)
    assert out.shape == (1600,)


@pytest.mark.realdata
def test_brisk_gist_every_gardens_point_frame_gives_25_tiles(data_root: Path) -> None:
    spec = get_descriptor("brisk-gist")
    frames = sorted((data_root / "gardens-point-walking" / "day_right").glob("*.jpg"))
    assert len(frames) == 200
    for path in frames:
        tiles = spec.compute(read_gray(path, spec.min_size)).reshape(25, 64)
        assert np.all(tiles.any(axis=1)), path.name


def test_registry_exports_the_metrics() -> None:
    assert registry.METRICS == METRICS == ("l1", "sqeuclidean", "hamming", "cosine")
