"""Data in: a dataset file read and checked into a :class:`Dataset` (captures, touches,
camera, tablet), its landmark arrays as :class:`Observations` and the :class:`Rig` they were
taken on; dataset files written, edited in place and converted; the points CSV of
``predict``. Files come in here and nowhere else."""
