"""The ``hil`` command line: one parser family, every error one stderr line and an exit code
(:data:`hil.errors.EXIT_CODES`). Entry point: :func:`hil.cli.main.main`."""


def __getattr__(name: str) -> object:
    """The names of the former module ``hil.cli`` (a façade: import them from their module)."""
    from hil import moved_attribute

    return moved_attribute(__name__, name)
