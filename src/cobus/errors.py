"""The root of every error cobus raises on purpose.

Each layer derives its own typed errors from :class:`CobusError`, so an application can catch
everything cobus reports with one ``except`` and still tell the causes apart.
"""


class CobusError(Exception):
    """Base class of all errors raised by cobus."""
