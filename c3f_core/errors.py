"""Error types shared by every package of the project.

`InputError` is what bad user input raises: a missing file, a wrong format, an option
out of range. Its message is one line and names the file or option. The command-line
entry points catch it and print ``error: <message>`` instead of a traceback.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input (file, format or option); the message names the culprit."""
