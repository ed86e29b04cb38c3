"""The benchmarks: `cosim bench` (command.py) and each figure's own module, run alone with
`python -m cosim.bench.<name>` where it says so. Measurements only: nothing outside this
package imports it but the CLI."""
