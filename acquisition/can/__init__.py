"""acquisition.can."""
