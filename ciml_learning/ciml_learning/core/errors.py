"""One exception base for CIML: every expected failure is a CimlError with a one-line message."""


class CimlError(Exception):
    """Base of CIML's domain errors; the CLI prints its message on one line and exits non-zero."""
