"""The one-source build of the project's packages: their per-tick modules are typed Python,
compiled by Cython into extension modules beside their sources (`build.py`, `python -m
onesource.build` or `make build`), and the switch (`switch.py`, COSIM_COMPILED) picks, once per
process, the compiled or the interpreted form. Each package lists its modules (`register`, in
its `__init__`); nothing here knows a package's contents."""
