"""Runs: photons traced in chunks on threads (``simulate``) or on a Dask cluster (``cluster``), sweeps of runs
(``sweep``), and the files a run writes (``results``).  Imports the estimators and the chamber below it.
"""
