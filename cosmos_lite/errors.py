"""Errors users can act on; each carries the CLI exit code that DESIGN.md assigns to it."""


class CosmosError(Exception):
    """Base class: a failure with a message that names the file or key and the fix."""

    exit_code = 1


class ConfigError(CosmosError):
    """Bad arguments or configuration (exit 2)."""

    exit_code = 2


class GuardrailBlocked(CosmosError):
    """A guardrail blocked the request (exit 3)."""

    exit_code = 3


class InputError(CosmosError):
    """Unreadable input: missing, corrupt or of the wrong kind (exit 4)."""

    exit_code = 4
