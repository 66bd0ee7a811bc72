"""estimator.classical."""
