"""``damper-hil fleet``: identify, validate and diagnose many dampers' dyno tests as Dask
tasks (docs/fleet.md).

:mod:`.inputs` finds each damper's test set, :mod:`.task` is the work of one damper (pure
computation, run on a worker), :mod:`.table` the one-row-per-damper results,
:mod:`.outliers` the rules that flag a damper, :mod:`.summary` the report,
:mod:`.runner` the run itself (resume, progress, writing), :mod:`.example` a virtual
production batch to try it on (:mod:`.scatter` its units' scatter and defects).
"""
