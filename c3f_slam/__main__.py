"""``python -m c3f_slam``: see :mod:`c3f_slam.cli.main`."""

import sys

from c3f_slam.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
