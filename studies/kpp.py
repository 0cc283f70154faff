"""Reproduce Fisher-KPP with noisy data (paper Section 3.2): standard vs noise-aware ECFM."""

import sys

from ecfm_uq.cli import main

raise SystemExit(main(["reproduce", "kpp", *sys.argv[1:]]))
