"""The ``bemlearn`` command line."""

from bemlearn.cli.main import main

__all__ = ["main"]
