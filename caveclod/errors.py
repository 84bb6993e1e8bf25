"""Errors that carry a one-line message for the user: what was wrong and what to do."""


class CaveclodError(Exception):
    """Base class of every error caveclod raises on purpose."""


class InputError(CaveclodError, ValueError):
    """The input mesh, heightfield or option is unusable as given."""


class FileFormatError(CaveclodError, ValueError):
    """A .cvc file is unreadable: truncated, corrupt, or of another version."""
