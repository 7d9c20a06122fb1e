"""The one exception type users see: a clear message naming the file, key or value at fault."""


class HelioflowError(Exception):
    """Bad input or configuration; the message names what is wrong and what was expected."""


class ConfigError(HelioflowError):
    """A config.yaml key or value is missing, unknown or out of range."""


class DataError(HelioflowError):
    """An input file is missing, corrupt, truncated or holds values of the wrong shape or range."""


class OutputError(HelioflowError):
    """An output file cannot be written (a full disk, no permission); nothing half-written is left."""
