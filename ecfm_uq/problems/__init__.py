"""Problem builders: each turns one of the paper's models into a GalerkinSystem (no solver
or optimizer logic here)."""
