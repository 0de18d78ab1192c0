"""The package's version: a leaf every floor may read (the store's and the report's
`code_version`; pyproject.toml reads it too)."""

__version__ = "0.1.0"
