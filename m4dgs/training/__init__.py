"""Training: configuration, variants, densification, data, the stages, V2W and the pipeline."""
