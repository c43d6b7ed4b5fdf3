"""Priors precomputed from the clip: epipolar and rigidity dynamic masks, initial cameras."""
