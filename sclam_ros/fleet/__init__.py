"""Many recordings on Dask distributed, one recording in time chunks on local processes (or a
cluster): discovery of inputs, the per-recording task, the results store, chunks, history.
May import: core, frontend, online, diagnosis, io."""
