"""The errors every entry point reports in one line (scripts/_cli.py), in a module that imports nothing, so
that a script's code fingerprint (lightcrafter.codeversion) does not depend on where they are raised."""


class DataError(ValueError):
    """A malformed input file. The message is one line naming the file and the fix."""


class ConfigError(ValueError):
    """An impossible configuration. The message names the key and the fix."""


class NoGPUError(RuntimeError):
    """A stage that must run on a GPU sees none."""
