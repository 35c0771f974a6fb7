"""Scenes: what a bench is and what to do with it, as validated documents.

* :mod:`hil.scene.spec` -- the scene schema (devices, plant, safety, controller and experiments
  composed from their registries, certification), its cross-checks, :func:`~hil.scene.spec.load_scene`
  and the built-in scenes in ``hil/scene/builtin/*.yaml``;
* :mod:`hil.scene.netfile` -- network files for ``hil stability --network`` (a transfer matrix with
  its immittance type and criterion).

Data flow: scene -> bench (:mod:`hil.bench`) -> run (:mod:`hil.run`) -> record (:mod:`hil.record`)
-> certify (:mod:`hil.certify`) -> report (:mod:`hil.report`).
"""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.scene`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
