"""Work beyond one run, on Dask: campaign replay of many logs, Monte Carlo studies."""
