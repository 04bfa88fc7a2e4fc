"""User-facing errors: every one of them prints as a single line, never a traceback."""


class PbvolError(Exception):
    """An error caused by the user's input (a file, a field, a value) or environment.

    ``str(err)`` is the complete one-line message shown to the user.
    """


class ConfigError(PbvolError):
    """A scene or material file that cannot be used: names the file, the field and what was expected."""

    def __init__(self, file, field: str | None, message: str):
        self.file = str(file)
        self.field = field
        self.message = message
        where = f"{self.file}: {field}: " if field else f"{self.file}: "
        super().__init__(where + message)


class RenderFailed(PbvolError):
    """A render that ran but whose image cannot be trusted (non-finite or absurd pixels): a bug, not bad input."""
