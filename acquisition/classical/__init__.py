"""acquisition.classical."""
