"""CAT-Graph: the particle filter, its rank observation model and its kernels."""
