"""The inverse problems: a model and its data, behind one interface."""
