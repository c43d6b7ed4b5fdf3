"""Foundations: camera conventions, rotations, splines, warping, SSIM, camera responses, HDR maths,
atomic I/O."""
