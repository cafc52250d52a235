"""How a frame maps onto a network's pixel grid (centre crop, then resize).

Pixel convention (as :mod:`c3f_slam.camera.intrinsics`): integer coordinates are pixel centres. A frame
pixel x inside the crop box [x0, x0 + crop_w) lands at network pixel
``x_net = (x - x0 + 0.5) * net_w / crop_w - 0.5`` (same for y); this is the mapping of
``cv2.resize`` (half-pixel centres) and of :meth:`PinholeCamera.resize`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from c3f_slam.camera.intrinsics import PinholeCamera

UPSAMPLING = {"linear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST_EXACT}


@dataclass(frozen=True)
class NetworkView:
    """The crop box of a frame and the network grid it is resized to.

    box: (x0, y0, w, h) of the centre crop in frame pixels (the whole frame without crop).
    frame: the frame's intrinsics; camera: the intrinsics of the network grid.
    """

    box: tuple[int, int, int, int]
    frame: PinholeCamera
    camera: PinholeCamera

    @classmethod
    def of(cls, frame: PinholeCamera, crop: tuple[int, int] | None, size: tuple[int, int]) -> NetworkView:
        """View for ``crop`` = (w, h) or None and network ``size`` = (w, h); InputError when
        the crop is larger than the frame."""
        box = frame.center_crop_box(*crop) if crop is not None else (0, 0, frame.width, frame.height)
        camera = frame.crop(*box).resize(*size)
        return cls(tuple(int(v) for v in box), frame, camera)

    @property
    def size(self) -> tuple[int, int]:
        """Network grid (width, height), pixels."""
        return self.camera.width, self.camera.height

    def frame_to_network(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) frame pixel coordinates (u, v) -> (N, 2) float64 network pixel coordinates."""
        x0, y0, w, h = self.box
        nw, nh = self.size
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.stack([(xy[:, 0] - x0 + 0.5) * nw / w - 0.5, (xy[:, 1] - y0 + 0.5) * nh / h - 0.5], axis=1)

    def network_to_frame(self, image: np.ndarray, interpolation: str = "linear") -> np.ndarray:
        """An (h_net, w_net) map resized back onto the crop box of an (H, W) frame-size map,
        0 outside the crop; ``interpolation`` ``linear`` or ``nearest`` (centre-aligned)."""
        x0, y0, w, h = self.box
        out = np.zeros((self.frame.height, self.frame.width), dtype=image.dtype)
        out[y0 : y0 + h, x0 : x0 + w] = cv2.resize(image, (w, h), interpolation=UPSAMPLING[interpolation])
        return out
