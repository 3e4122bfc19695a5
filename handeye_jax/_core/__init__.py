"""The plumbing every layer may use, without JAX: the one input error, reading with limits
(numbers, files, JSON), atomic writes, Ctrl-C handling, progress bars and the plain constants
the command line's help shows. Nothing here imports JAX, equinox or OpenCV (a test checks)."""
