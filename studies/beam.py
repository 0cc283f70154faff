"""Reproduce the stochastic beam inverse problem with pseudo-likelihood constraint forces
(paper Section 3.3)."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "beam", *sys.argv[1:]]))
