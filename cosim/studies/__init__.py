"""Studies at scale (issue 15): sweeps and Monte Carlo on Dask, resumable, reported with
statistics. engine.py runs jobs (serial, local pool, dask.distributed), table.py streams rows
into results.csv, dists.py parses `--vary` and draws, study.py ties a study to its folder,
report.py writes report.md/json and plots, command.py is the command line."""
