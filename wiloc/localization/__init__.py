"""A localization run: its session (method, map, rows), batch and streaming, following a folder."""
