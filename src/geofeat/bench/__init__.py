"""The matching-score benchmark: protocols, runner, report."""
