"""Reproduce the ``geometry`` study (paper Section 4): ``python studies/geometry.py --out DIR``."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "geometry", *sys.argv[1:]]))
