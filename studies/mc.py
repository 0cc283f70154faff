"""Reproduce the Monte Carlo vs PCE verification of the beam (paper Section 3.3)."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "mc", *sys.argv[1:]]))
