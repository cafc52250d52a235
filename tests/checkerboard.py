"""A checkerboard image for the calibration and lens tests."""

import numpy as np


def board_image(board: tuple[int, int], px: int) -> np.ndarray:
    """A board of ``board`` = (cols, rows) inner corners: its squares with a white border of one
    square, ``px`` pixels a square (grey uint8)."""
    nx, ny = board[0] + 1, board[1] + 1
    img = np.full(((ny + 2) * px, (nx + 2) * px), 255, np.uint8)
    for j in range(ny):
        for i in range(nx):
            if (i + j) % 2 == 0:
                img[(j + 1) * px:(j + 2) * px, (i + 1) * px:(i + 2) * px] = 0
    return img
