"""Errors that carry a one-line message for the user: what was wrong and what to do."""


class CaveclodError(Exception):
    """Base class of every error caveclod raises on purpose."""


class InputError(CaveclodError, ValueError):
    """The input mesh, heightfield or option is unusable as given."""


class FileFormatError(CaveclodError, ValueError):
    """A .cvc file is unreadable: truncated, corrupt, or of another version."""


class MeshDamagedError(FileFormatError):
    """A static mesh broke a rule no built mesh breaks while a camera refined it:
    its file is damaged in a way the checks at load time cannot see."""
