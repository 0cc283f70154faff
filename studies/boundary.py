"""Reproduce the ``boundary`` study (paper Section 4): ``python studies/boundary.py --out DIR``."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "boundary", *sys.argv[1:]]))
