"""Reproduce the Burgers dynamic inverse problem (paper Section 3.1), standard and ECFM."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "burgers", *sys.argv[1:]]))
