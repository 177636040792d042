"""``needle_batch``: the offline pipeline fanned out over bags x parameter sets on Dask distributed (sweeps and
tissue identification). Needs ``dask[distributed]``, pandas and pyarrow; the rest of the package does not."""
