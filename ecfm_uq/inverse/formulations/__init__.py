"""The inverse formulations: how each one turns a problem into an estimate."""
