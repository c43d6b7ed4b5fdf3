"""Calibration rows: 2D predictions that reconstruct nothing in 3D, scored like a method, so that
every table says how much a method adds over 2D (eval.calibration.predict), with a camera response
estimated from the bracketed training frames (eval.calibration.response, Debevec-Malik)."""
