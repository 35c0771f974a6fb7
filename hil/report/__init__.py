"""Reports of a certificate: HTML (jinja2 templates in ``hil/report/templates``), PDF, JSON.

* :mod:`hil.report.render` -- ``build_reports`` / ``hil report``;
* :mod:`hil.report.sections` -- which sections a certificate's report holds (left out when the
  scene does not need them) and their content.
"""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.report`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
