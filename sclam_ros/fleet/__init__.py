"""Many recordings, and one long recording in parallel, on Dask distributed: discovery of inputs,
the per-recording task, the results store, time-chunked registration and calibration history.
May import: core, frontend, online, diagnosis, io."""
