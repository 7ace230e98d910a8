"""The exception hierarchy: every error OSLIM raises on purpose is an OslimError."""


class OslimError(Exception):
    """Base of all OSLIM errors."""


class ConfigError(OslimError):
    """A configuration file or override is missing, malformed or out of range."""


class LinkError(OslimError):
    """A MAVLink or Zenoh link could not be opened or was lost."""


class NoPathError(OslimError):
    """No admissible path exists between two cells (obstacles or area bounds)."""


class OutsideAreaError(OslimError):
    """A position lies outside the search area."""
