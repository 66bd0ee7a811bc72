"""acquisition.sim."""
