"""Training data: HDF5 datasets, splits and folds, and where materials come from (files, proxies, analytic)."""
