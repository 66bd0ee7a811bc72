"""ptinertia.report.build."""
