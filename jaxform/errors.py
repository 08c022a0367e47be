"""The error a user's input raises: every layer that checks input raises it, and the CLI
turns it into one line and exit status 2.  This module imports nothing of jaxform."""


class ConfigError(ValueError):
    """Invalid input (a config key, a material file, a design set-up); the message names
    the dotted key, flag or file and what is allowed."""
