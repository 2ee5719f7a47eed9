"""The package's version, in a module of its own so that any layer can read it without importing the package root
(which is the top of the layers, docs/architecture.md)."""

__version__ = "0.2.0"
