"""Certification: from a scene to a sealed GO / MARGINAL / NO-GO certificate.

* :mod:`hil.certify.pipeline` -- ``certify_scene``: the stages run, identify, nominal, robust,
  design, decide, witness, then seal;
* :mod:`hil.certify.stages` -- the stages' typed outputs and the measurements' declared limits;
* :mod:`hil.certify.statistics` -- P(stable) (Clopper-Pearson), thinning, worst-case margins,
  the decision policy;
* :mod:`hil.certify.certificate` -- the certificate record, its canonical form and digest;
* :mod:`hil.certify.signing`, :mod:`hil.certify.verify` -- signatures and ``hil verify``;
* :mod:`hil.certify.figures` -- the evidence plots a certificate carries; :mod:`hil.certify.units`
  the units of its numbers;
* :mod:`hil.certify.sweep`, :mod:`hil.certify.fleet` -- ``hil sweep`` and fleet certification.
"""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.certify`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
