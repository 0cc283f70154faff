"""What a fit says about the data: uncertainty, verdicts, profiles, posteriors."""
