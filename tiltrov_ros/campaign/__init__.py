"""``tiltrov campaign``: Monte-Carlo campaigns run on Dask (the ``campaign`` extra).

The campaign file, its samples and the hold criterion are pure and live in
:mod:`tiltrov_ros.core.campaign`; this package runs them:

* :mod:`.plan` - the runs (sample x configuration) and the files that
  reproduce one with ``tiltrov sim``;
* :mod:`.worker` - what a worker does with a batch of runs (no Dask);
* :mod:`.execute` - the Dask cluster (local, or an external scheduler) and
  the batches;
* :mod:`.table` - ``runs.csv``, appended as runs finish, read by ``--resume``;
* :mod:`.summary`, :mod:`.figures` - hold rates, percentiles, worst runs;
* the command itself is :mod:`tiltrov_ros.cli.campaign`.

Only :mod:`.execute` imports Dask, and only :mod:`.figures` matplotlib.
"""
