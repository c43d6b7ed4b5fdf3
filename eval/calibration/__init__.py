"""Calibration rows: 2D predictions that reconstruct nothing in 3D, scored like a method, so that
every table says how much a method adds over 2D (eval.calibration.predict), with a camera response
estimated from the bracketed training frames (eval.calibration.response, Debevec-Malik)."""

# the calibration rows a suite row may name (`calibration: ROW`, eval.records.suite): the first two
# predict the temporal test frames (eval.calibration.frames), dibr the held-out views
# (eval.experiments.dibr_views)
TEMPORAL_ROWS = ("copy-nearest", "flow-merge")
VIEW_ROWS = ("dibr",)
ROWS = TEMPORAL_ROWS + VIEW_ROWS
# the `variant` of a calibration row (suite definitions, runs CSV): it trains nothing
VARIANT = "calibration"
# the rows whose prediction is the same for every trainer seed (dibr's camera initialisation is
# seeded): a table counts each scene of theirs once (eval.tables.TableSpec.seed_free)
SEED_FREE_ROWS = TEMPORAL_ROWS
