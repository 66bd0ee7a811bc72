"""ptinertia.viewer.rerun_sink."""
