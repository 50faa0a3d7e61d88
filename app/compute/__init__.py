"""What runs in worker processes (local, synchronous pool, Dask): the solver tasks and process setup. No web framework, no database."""
