"""Run records and data recorded elsewhere.

* :mod:`hil.record.hdf5` -- the HDF5 run record (:class:`~hil.record.hdf5.RunRecord`, the
  :class:`~hil.record.hdf5.RecordWriter` that flushes every block as it fills), ``hil replay``;
* :mod:`hil.record.importers` -- CSV and MATLAB records from other benches;
* :mod:`hil.record.identify_source` -- records as :mod:`hil.identify` reads them (the
  ``hil.identify.record_backends`` entry point);
* :mod:`hil.record.outdir` -- output folders that never overwrite what is there.
"""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.record`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
