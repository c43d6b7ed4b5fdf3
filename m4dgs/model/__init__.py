"""The representation: Gaussians, colour, tone mapper, background, rendering, and a trained
model."""
