"""Describing traversals into the cache (in this process, worker processes or a Dask cluster), and the difference rows between them."""
