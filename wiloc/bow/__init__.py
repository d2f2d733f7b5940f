"""Bag-of-words: local features, their clustering into a vocabulary, and FAB-MAP's model."""
