"""wiloc's version, in one place: the package metadata reads it from here (pyproject.toml), and
results headers, cache entries and vocabularies record it."""

__version__ = "0.1.0"
