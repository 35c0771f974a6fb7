"""hil: hardware-in-the-loop identification and stability certification.

One import namespace over four top-level folders; inside ``hil/`` the subpackages follow the data
flow (docs/ARCHITECTURE.md):

* ``hil.scene`` -- scene and network files (schemas, cross-checks, built-in scenes);
* ``hil.experiments``, ``hil.controllers`` -- experiment types and controllers (each with its
  own schema, registered; the scene composes them);
* ``hil.bench`` -- devices behind protocol adapters, real or simulated behind real transports;
* ``hil.run`` -- the fixed-rate loop (lockstep or realtime), safety, watchdog, safe stop;
* ``hil.record`` -- HDF5 run records, imported records;
* ``hil.identify`` -- frequency-response estimation, grey-box fits, emcee posteriors;
* ``hil.models`` -- the papers' network models (SDEA/VSIC, MCET trilateral, ...);
* ``hil.stability`` -- LTI network models, immittance conversions and exact stability criteria;
* ``hil.certify`` -- the certification stages and the sealed certificate;
* ``hil.report`` -- HTML / PDF / JSON reports;
* ``hil.cli`` -- the ``hil`` command;
* ``hil.protocols`` -- role interfaces and device adapters over real transports;
* ``hil.mocks`` -- simulated plants and simulated devices behind real transports.

Heavy or device-specific dependencies are imported lazily by the modules that need them.

Modules that moved when ``hil/`` was split into these subpackages keep their old import paths
(``hil.pipeline``, ``hil.scene`` names, ...): importing an old path gives the *same* module object
as the new one (so ``monkeypatch.setattr`` on either reaches the code) with a
``DeprecationWarning`` naming the new path (:data:`MOVED_MODULES`).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

from hil.errors import HilError

__all__ = ["MOVED_INTO_PACKAGE", "MOVED_MODULES", "HilError", "__version__", "moved_attribute"]
__version__ = "0.1.0"

#: old module path -> new module path (the split of the flat hil/ folder, issue 13)
MOVED_MODULES: dict[str, str] = {
    "hil.netfile": "hil.scene.netfile",
    "hil.probe": "hil.bench.probe",
    "hil.stopflag": "hil.bench.stopflag",
    "hil.mocks.serve": "hil.bench.serve",
    "hil.mocks.lti": "hil.lti",
    "hil.runner": "hil.run.runner",
    "hil.realtime": "hil.run.realtime",
    "hil.plan": "hil.run.plan",
    "hil.importers": "hil.record.importers",
    "hil.identify_records": "hil.record.identify_source",
    "hil.outdir": "hil.record.outdir",
    "hil.pipeline": "hil.certify.pipeline",
    "hil.certify_stages": "hil.certify.stages",
    "hil.certificate": "hil.certify.certificate",
    "hil.signing": "hil.certify.signing",
    "hil.verify": "hil.certify.verify",
    "hil.sweep": "hil.certify.sweep",
    "hil.fleet": "hil.certify.fleet",
    "hil.evidence_plots": "hil.certify.figures",
    "hil.report_units": "hil.certify.units",
    "hil.report_model": "hil.report.sections",
}


class _MovedLoader(importlib.abc.Loader):
    """Loads an old module path as the module at its new path (the same object)."""

    def __init__(self, new: str) -> None:
        self.new = new
        self._spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(self.new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self._spec  # importlib set the alias spec: the module keeps its own


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        new = MOVED_MODULES.get(fullname)
        if new is None:
            return None
        warnings.warn(f"{fullname} moved to {new}", DeprecationWarning, stacklevel=2)
        return importlib.machinery.ModuleSpec(fullname, _MovedLoader(new))


#: old module path that is now a package's name -> the module its names moved to; the package
#: gives them on attribute access (``from hil.bench import Bench`` still works)
MOVED_INTO_PACKAGE: dict[str, str] = {
    "hil.scene": "hil.scene.spec",
    "hil.bench": "hil.bench.runtime",
    "hil.record": "hil.record.hdf5",
    "hil.certify": "hil.certify.statistics",
    "hil.report": "hil.report.render",
    "hil.cli": "hil.cli.main",
}


def moved_attribute(package: str, name: str) -> object:
    """The attribute ``name`` of the module that ``package`` was before it became a package
    (called by that package's ``__getattr__``; :class:`AttributeError` when it has none)."""
    if name.startswith("__"):
        raise AttributeError(name)
    module = importlib.import_module(MOVED_INTO_PACKAGE[package])
    try:
        value = getattr(module, name)
    except AttributeError:
        raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
    warnings.warn(f"{package}.{name} moved to {module.__name__}.{name}", DeprecationWarning, stacklevel=3)
    return value


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    sys.meta_path.insert(0, _MovedFinder())
