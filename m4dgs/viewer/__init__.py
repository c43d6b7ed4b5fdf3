"""`m4dgs view`: an interactive browser viewer of a trained run or of a clip (docs/viewer.md).

m4dgs.viewer.cameras   pinhole cameras (ViewCamera), the browser camera <-> OpenCV pose, the run's
                       named cameras (training, test and the clip's held-out views)
m4dgs.viewer.frame     view_frame: one displayed image (LDR, HDR mu-law / false colour, depth,
                       static/dynamic split, Gaussian centres) of a model at a camera, time, EV
m4dgs.viewer.truth     the ground truth at a named camera and the per-pixel error
m4dgs.viewer.clipview  a clip's frames with their priors drawn over them
m4dgs.viewer.server    the viser server: GUI, render loop, scene (frusta, path, centres)
m4dgs.viewer.web       what both servers share: importing viser, the wide-host warning

viser is an optional dependency (the `viewer` extra), imported only when a server starts."""
