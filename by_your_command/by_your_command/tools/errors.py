"""The errors of the tools package (all ValueErrors: callers that only report them may catch that)."""

from __future__ import annotations


class ToolsConfigError(ValueError):
    """tools.yaml (or the interfaces it names) is unusable; the text names the tool and the key."""


class ToolArgumentError(ValueError):
    """The model's arguments are wrong; the text (read by the model, maybe spoken) says which and why."""


class CatalogError(ValueError):
    """A catalog received over the bridge is malformed (it is untrusted input)."""
