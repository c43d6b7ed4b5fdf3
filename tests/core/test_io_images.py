"""m4dgs.core.io image readers and writers (OpenImageIO): exact round trips, channel layouts,
byte-reproducible files, no silent quantisation of 16-bit PNGs, and safety across fork."""

from __future__ import annotations

import multiprocessing as mp
import struct
import sys
import zlib

import numpy as np
import pytest

from m4dgs.core import io as mio


def _png16(path, rgb16: np.ndarray) -> None:
    """A 16-bit RGB PNG written by hand (zlib + struct), independent of the code under test."""
    h, w, _ = rgb16.shape

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + kind
            + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
        )

    rows = b"".join(b"\x00" + rgb16[y].astype(">u2").tobytes() for y in range(h))
    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0)  # 16 bit, colour type 2 (RGB)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("shape", [(7, 5), (7, 5, 3), (7, 5, 4), (7, 5, 1)])
def test_exr_round_trip_is_exact(tmp_path, shape):
    rng = np.random.default_rng(0)
    img = (rng.standard_normal(shape) * 100).astype(np.float32)
    img.flat[0] = 6.5e4  # beyond half range: stored as float32
    p = tmp_path / "a.exr"
    mio.write_exr(p, img)
    back = mio.read_exr(p)
    want = img[..., 0] if img.ndim == 3 and img.shape[2] == 1 else img
    assert back.dtype == np.float32 and back.shape == want.shape
    np.testing.assert_array_equal(back, want)


def test_same_image_gives_the_same_bytes(tmp_path):
    img = np.random.default_rng(1).random((6, 9, 3)).astype(np.float32)
    for name, write in (("a.exr", mio.write_exr), ("a.png", mio.write_png)):
        p1, p2 = tmp_path / f"1{name}", tmp_path / f"2{name}"
        write(p1, img)
        write(p2, img)
        assert p1.read_bytes() == p2.read_bytes(), name


def test_png_round_trip_and_rounding(tmp_path):
    rng = np.random.default_rng(2)
    rgb = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
    mio.write_png(tmp_path / "rgb.png", rgb)
    np.testing.assert_array_equal(mio.read_png(tmp_path / "rgb.png"), rgb)
    grey = rng.integers(0, 256, (4, 6), dtype=np.uint8)
    mio.write_png(tmp_path / "g.png", grey)
    np.testing.assert_array_equal(mio.read_png(tmp_path / "g.png"), grey)
    # floats are rounded to the nearest code, clipped to [0, 255]
    f = np.array([[[0.0, 0.5 / 255 + 1e-6, 1.7]], [[-0.2, 254.4 / 255, 1.0]]], np.float32)
    mio.write_png(tmp_path / "f.png", f)
    np.testing.assert_array_equal(
        mio.read_png(tmp_path / "f.png"), np.array([[[0, 1, 255]], [[0, 254, 255]]], np.uint8)
    )


def test_16bit_png_is_refused_by_read_png_and_read_exactly_by_read_image(tmp_path):
    rgb16 = np.random.default_rng(3).integers(0, 65536, (5, 4, 3)).astype(np.uint16)
    p = tmp_path / "deep.png"
    _png16(p, rgb16)
    with pytest.raises(mio.FileFormatError, match="16-bit PNG"):
        mio.read_png(p)
    px, kind = mio.read_image(p)
    assert kind == "uint16"
    np.testing.assert_array_equal(px, rgb16)


def test_missing_and_corrupt_files_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.exr"):
        mio.read_exr(tmp_path / "nope.exr")
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an image")
    with pytest.raises(mio.FileFormatError, match="bad.exr"):
        mio.read_exr(bad)


def _child_writes_and_reads(folder: str) -> None:
    img = np.full((256, 384, 3), 0.25, np.float32)
    mio.write_exr(f"{folder}/child.exr", img)
    assert float(mio.read_exr(f"{folder}/child.exr").mean()) == 0.25


@pytest.mark.skipif(sys.platform != "linux", reason="fork start method")
def test_exr_io_works_in_a_forked_child_after_the_parent_used_it(tmp_path):
    """OpenEXR's thread pool is inherited without its threads: without the fork hook the child's
    first write waits forever (this test then fails on its timeout)."""
    img = np.random.default_rng(4).random((256, 384, 3)).astype(np.float32)
    mio.write_exr(tmp_path / "parent.exr", img)  # the parent's pools now have threads
    mio.read_exr(tmp_path / "parent.exr")
    for _ in range(2):
        proc = mp.get_context("fork").Process(target=_child_writes_and_reads, args=(str(tmp_path),))
        proc.start()
        proc.join(timeout=60)
        if proc.is_alive():
            proc.kill()
            proc.join()
            pytest.fail("EXR I/O in a forked child hung")
        assert proc.exitcode == 0
    # the parent keeps its pools and still works
    np.testing.assert_array_equal(mio.read_exr(tmp_path / "parent.exr"), img)
