"""``python -m c3f_demo --out DIR [--quick] [--from-scratch] [--overwrite]``, or on your own
recording ``python -m c3f_demo --video FILE [--camera camera.json | --fov DEG] --out DIR``."""

import sys

from c3f_demo.cli import main

if __name__ == "__main__":
    sys.exit(main())
