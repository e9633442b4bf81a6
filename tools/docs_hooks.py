"""MkDocs hook: every public function, class and method of the modules the API reference shows
has a docstring. A missing one is a warning, so `mkdocs build --strict` (run by `make test`)
fails on it: the reference is generated from the docstrings and would show an empty entry."""

from __future__ import annotations

import re
from pathlib import Path

import griffe
from mkdocs.plugins import get_plugin_logger

log = get_plugin_logger(__name__)
SHOWN = re.compile(r"^::: ([\w.]+)", re.MULTILINE)


def undocumented(obj: griffe.Object, prefix: str = "") -> list[str]:
    """Public functions, classes and methods under ``obj`` without a docstring."""
    missing = []
    for name, member in obj.members.items():
        if name.startswith("_") or member.is_alias or member.kind not in (griffe.Kind.FUNCTION, griffe.Kind.CLASS):
            continue
        if not member.docstring:
            missing.append(prefix + name)
        if member.kind is griffe.Kind.CLASS:
            missing += undocumented(member, f"{prefix}{name}.")
    return missing


def on_pre_build(config) -> None:
    root = Path(config["docs_dir"]).parent
    pages = sorted(Path(config["docs_dir"], "reference").glob("*.md"))
    modules = [module for page in pages for module in SHOWN.findall(page.read_text())]
    package = griffe.load("styleerd", search_paths=[str(root)])
    for module in modules:
        obj = package if module == "styleerd" else package[module.removeprefix("styleerd.")]
        for name in undocumented(obj):
            log.warning(f"{module}.{name} has no docstring (the API reference shows it)")
