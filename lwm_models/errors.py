"""Exception types of the core. Every bad input raises one of these, with a message naming the problem."""


class LwmError(Exception):
    """Base class of every error the core raises on bad input."""


class InvalidActionError(LwmError, ValueError):
    """An action outside 0..4, or a batch of actions of the wrong shape."""


class InvalidSpecError(LwmError, ValueError):
    """A malformed game spec: unknown names, duplicate identities, missing or repeated roles."""


class ShapeError(LwmError, ValueError):
    """An array of the wrong shape or dtype."""


class TextFileError(LwmError, ValueError):
    """A description file that cannot be used: not JSON, missing keys, empty lists."""


class GameStateError(LwmError, RuntimeError):
    """An operation that the game's current state does not allow (e.g. step before reset)."""


class DatasetError(LwmError, ValueError):
    """A dataset directory that is missing files or does not match its index."""
