"""Jobs: the job table, the store that owns every state change, the dispatcher and its executors (local processes, Dask)."""
