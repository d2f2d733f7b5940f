"""Ground truth, metrics, calibration scores, results files and the comparison of runs."""
