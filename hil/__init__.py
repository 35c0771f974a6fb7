"""hil: hardware-in-the-loop identification and stability certification.

Sub-packages (one import namespace over four top-level folders):

* ``hil.stability`` -- LTI network models, immittance conversions and exact stability criteria.
* ``hil.models`` -- the papers' built-in network models (SDEA/VSIC, MCET trilateral, ...).
* ``hil.identify`` -- frequency-response estimation, grey-box fits, emcee posteriors.
* ``hil.protocols`` -- role interfaces and device adapters over real transports.
* ``hil.mocks`` -- simulated plants and simulated devices behind real transports.

Heavy or device-specific dependencies are imported lazily by the modules that need them.
"""

from hil.errors import HilError

__all__ = ["HilError", "__version__"]
__version__ = "0.1.0"
