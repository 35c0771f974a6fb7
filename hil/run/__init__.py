"""Running experiments on a bench at a fixed rate.

* :mod:`hil.run.runner` -- :class:`~hil.run.runner.Runner`: the fixed-rate loop (lockstep or
  realtime), safety limits, watchdog, safe stop, the record written as it goes;
* :mod:`hil.run.realtime` -- deadlines, scheduling (SCHED_FIFO, mlockall, affinity), wake-up
  latency (``hil check-realtime``), lateness as measurements;
* :mod:`hil.run.plan` -- ``hil plan``: the predicted parameter uncertainty of a scene's experiments.

The experiment types and controllers (:mod:`hil.experiments`, :mod:`hil.controllers`) sit below
the scene, which composes their schemas.
"""
