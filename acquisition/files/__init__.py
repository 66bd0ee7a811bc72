"""acquisition.files."""
