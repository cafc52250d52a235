"""``python -m c3f_demo --out DIR [--quick] [--from-scratch] [--overwrite]``."""

import sys

from c3f_demo.cli import main

if __name__ == "__main__":
    sys.exit(main())
