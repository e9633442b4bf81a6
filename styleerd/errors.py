"""The one error type users see: the CLI prints its message on one line and exits with 2."""

import difflib


class StyleERDError(Exception):
    """Bad input or an impossible request, explained in the message."""


def unknown_name(what: str, name: object, names: tuple[str, ...] | list[str]) -> StyleERDError:
    """The error for a ``name`` not among ``names`` (a style, a content): the nearest one where it
    looks like a typo or a capital, and every valid one."""
    near = difflib.get_close_matches(str(name)[:40].lower(), names, 1)
    meant = f" (did you mean {near[0]!r}?)" if near else ""
    return StyleERDError(f"unknown {what} {name!r}{meant}; valid: {', '.join(names)}")
