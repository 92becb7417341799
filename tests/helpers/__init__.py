"""Helpers shared by the test files, one module per topic: test files import from here, never
from one another."""
