"""Errors the runtime raises for bad input: one line, naming the file/channel/shape."""


class InputError(ValueError):
    """Bad user input (file, channel, shape, value). The message is one line, ready to print."""
