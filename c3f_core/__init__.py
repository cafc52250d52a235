"""c3f_core: the project's shared kernel, the bottom layer every package may import.

Torch-free and free of the other packages: ``errors`` (``InputError``: bad user input, one
line), ``settings`` (frozen settings dataclasses read and changed by dotted paths),
``cli_parser`` (the one-line-error argparse parser), ``atomic`` (writes that never leave a
half-written file).
"""
