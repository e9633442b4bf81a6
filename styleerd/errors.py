"""The one error type users see: the CLI prints its message on one line and exits with 2."""


class StyleERDError(Exception):
    """Bad input or an impossible request, explained in the message."""
