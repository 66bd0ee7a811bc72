"""Helpers shared by the tests (independent forward models, fixtures)."""
