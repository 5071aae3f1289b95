"""``damper-hil tune``: virtual damper tuning on Dask (docs/tune.md).

:mod:`ride_sim.tuning` holds the design space, the objectives and the front;
:mod:`.runner` runs the search (chunks of designs as Dask tasks); :mod:`.report` writes
the results (``pareto.json``/``.csv``, a params file per front design, plots, summary).
"""
