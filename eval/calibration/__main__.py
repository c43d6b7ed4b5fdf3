"""python -m eval.calibration CLIP ROW OUT: a calibration row's prediction folder (eval.calibration
.frames), for `m4dgs-eval score-frames --clip CLIP --pred OUT --name ROW`."""

from __future__ import annotations

import sys

from m4dgs.clip import Clip

from .frames import ROWS, write_prediction


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 3 or args[1] not in ROWS:
        print(f"usage: python -m eval.calibration CLIP {{{'|'.join(ROWS)}}} OUT", file=sys.stderr)
        return 2
    print(write_prediction(Clip.open(args[0]), args[2], args[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
