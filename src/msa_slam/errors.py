"""One exception type for bad user input, so the CLI can print it as a single clear line."""


class InputError(ValueError):
    """Bad user input: the message names the file/frame/parameter and what is wrong."""
